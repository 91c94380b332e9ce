//! The DL-RS1A on a pty.

use super::device::{DlRs1aDevice, LaserSource, Output, SimKeyenceConfig};
use std::sync::{Arc, Mutex};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::task::JoinHandle;

/// Longest command line accepted; longer input is dropped with `ER,??,20`.
pub const MAX_COMMAND: usize = 256;

/// A running simulated DL-RS1A. Dropping it stops the server.
pub struct SimKeyence {
    path: String,
    device: Arc<Mutex<DlRs1aDevice>>,
    task: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for SimKeyence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimKeyence")
            .field("path", &self.path)
            .finish()
    }
}

impl Drop for SimKeyence {
    fn drop(&mut self) {
        if let Some(t) = &self.task {
            t.abort();
        }
    }
}

impl SimKeyence {
    /// The pty path the client opens.
    pub fn path(&self) -> &str {
        &self.path
    }
    /// Commands received so far.
    pub fn log(&self) -> Vec<String> {
        self.device
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .log
            .clone()
    }
    /// Hand the server task to the `sim serve` registry.
    pub fn into_endpoint(mut self, device: &str, protocol: &str) -> crate::serve::Endpoint {
        crate::serve::Endpoint {
            device: device.into(),
            protocol: protocol.into(),
            addr: None,
            path: Some(self.path.clone()),
            task: self.task.take(),
        }
    }
}

/// Serve a DL-RS1A on a new pty; returns once the pty exists.
pub fn serve_pty(
    source: Arc<dyn LaserSource>,
    config: SimKeyenceConfig,
) -> std::io::Result<SimKeyence> {
    use serialport::SerialPort as _;
    let (master, slave) = serialport::TTYPort::pair().map_err(std::io::Error::other)?;
    let path = slave
        .name()
        .ok_or_else(|| std::io::Error::other("pty without a name"))?;
    let master = tokio_serial::SerialStream::try_from(master).map_err(std::io::Error::other)?;
    let device = Arc::new(Mutex::new(DlRs1aDevice::new(source, config)));
    let dev = device.clone();
    let task = tokio::spawn(async move {
        let _slave = slave;
        let _ = session(master, dev).await;
    });
    Ok(SimKeyence {
        path,
        device,
        task: Some(task),
    })
}

async fn pause(device: &Arc<Mutex<DlRs1aDevice>>, secs: f64) {
    let clock = device.lock().unwrap_or_else(|e| e.into_inner()).clock();
    match clock {
        Some(c) => c.sleep(secs).await,
        None if secs.is_finite() && secs > 0.0 => {
            tokio::time::sleep(std::time::Duration::from_secs_f64(secs.min(3600.0))).await
        }
        None => {}
    }
}

async fn session<S: AsyncRead + AsyncWrite + Unpin>(
    mut io: S,
    device: Arc<Mutex<DlRs1aDevice>>,
) -> std::io::Result<()> {
    let mut buf: Vec<u8> = Vec::new();
    let mut scratch = [0u8; 1024];
    loop {
        let n = io.read(&mut scratch).await?;
        if n == 0 {
            return Ok(());
        }
        buf.extend_from_slice(&scratch[..n]);
        // The unit accepts CR or CR LF as the delimiter.
        while let Some(pos) = buf.iter().position(|&b| b == b'\r') {
            let raw: Vec<u8> = buf.drain(..=pos).take(pos).collect();
            let line: Vec<u8> = raw.into_iter().filter(|&b| b != b'\n').collect();
            if line.is_empty() {
                continue;
            }
            let (out, delay) = {
                let mut d = device.lock().unwrap_or_else(|e| e.into_inner());
                (d.handle_line(&line), d.reply_delay_s())
            };
            match out {
                Output::Send(b) => {
                    pause(&device, delay).await;
                    io.write_all(&b).await?;
                }
                Output::Delayed(b, secs) => {
                    pause(&device, secs).await;
                    io.write_all(&b).await?;
                }
                Output::Nothing => {}
            }
            io.flush().await?;
        }
        if buf.len() > MAX_COMMAND {
            buf.clear();
            io.write_all(b"ER,??,20\r\n").await?;
        }
    }
}
