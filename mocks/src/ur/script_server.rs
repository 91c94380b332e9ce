//! Script interface (30001–30003): URScript text in; a complete program replaces the running
//! one. Nothing is streamed back (ur_rtde never reads 30003, and unread data would block).
//!
//! A program is `def`/`sec` in column 1 … `end` in column 1; a non-indented line outside a
//! program is run as a one-line program. Faults (queue `<device>/script`): `DropLink` closes
//! the connection instead of running the program.

use super::controller::Controller;
use crate::world::Fault;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::net::{TcpListener, TcpStream};

/// Longest program accepted (ur_rtde's control script is ~60 KB).
pub const MAX_PROGRAM: usize = 1 << 20;

/// Accept script clients forever.
pub async fn serve(listener: TcpListener, ctrl: Arc<Controller>) {
    loop {
        match listener.accept().await {
            Ok((sock, _)) => {
                tokio::spawn(connection(sock, ctrl.clone()));
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}

/// Collects lines into programs.
#[derive(Debug, Default)]
pub struct ProgramAssembler {
    buf: String,
    open: bool,
}

impl ProgramAssembler {
    /// Feed one line (without its newline); returns a complete program when one ends.
    pub fn push(&mut self, line: &str) -> Option<String> {
        let starts_block = line.starts_with("def ") || line.starts_with("sec ");
        if !self.open {
            if starts_block {
                self.open = true;
                self.buf.clear();
                self.buf.push_str(line);
                self.buf.push('\n');
                return None;
            }
            let t = line.trim();
            if t.is_empty() || line.starts_with(' ') || line.starts_with('\t') {
                return None;
            }
            return Some(format!("{t}\n"));
        }
        if self.buf.len() + line.len() > MAX_PROGRAM {
            self.open = false;
            self.buf.clear();
            return None;
        }
        self.buf.push_str(line);
        self.buf.push('\n');
        if line.trim_end() == "end" {
            self.open = false;
            return Some(std::mem::take(&mut self.buf));
        }
        None
    }
}

async fn connection(sock: TcpStream, ctrl: Arc<Controller>) {
    let queue = format!("{}/script", ctrl.device);
    let mut lines = BufReader::new(sock).lines();
    let mut asm = ProgramAssembler::default();
    while let Ok(Some(line)) = lines.next_line().await {
        if line.len() > MAX_PROGRAM {
            return;
        }
        if let Some(program) = asm.push(&line) {
            if let Some(Fault::DropLink) = ctrl.world.take_fault(&queue) {
                return;
            }
            ctrl.run_program(program);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assembles_programs_and_single_lines() {
        let mut a = ProgramAssembler::default();
        assert_eq!(a.push("def p():"), None);
        assert_eq!(a.push("  movej([0,0,0,0,0,0])"), None);
        assert_eq!(a.push("  def inner():"), None);
        assert_eq!(a.push("  end"), None);
        assert_eq!(
            a.push("end"),
            Some("def p():\n  movej([0,0,0,0,0,0])\n  def inner():\n  end\nend\n".into())
        );
        assert_eq!(a.push("stopj(2)"), Some("stopj(2)\n".into()));
        assert_eq!(a.push("   "), None);
    }
}
