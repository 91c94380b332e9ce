//! Transports for the simulated tracker: a TCP listener (Vega) and a pty (serial Polaris).

use super::device::{NdiDevice, Output, SimNdiConfig, TrackerSource};
use super::wire;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::task::JoinHandle;

/// Longest command line accepted (bytes); longer lines get `ERROR02`.
pub const MAX_COMMAND: usize = 4096;

/// A running simulated tracker. Dropping it stops the server.
pub struct SimNdi {
    addr: Option<SocketAddr>,
    path: Option<String>,
    device: Arc<Mutex<NdiDevice>>,
    tasks: Vec<JoinHandle<()>>,
}

impl std::fmt::Debug for SimNdi {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimNdi")
            .field("addr", &self.addr)
            .field("path", &self.path)
            .finish()
    }
}

impl Drop for SimNdi {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

impl SimNdi {
    /// The bound TCP address (TCP servers).
    pub fn addr(&self) -> Option<SocketAddr> {
        self.addr
    }
    /// The pty path a client opens (serial servers).
    pub fn path(&self) -> Option<&str> {
        self.path.as_deref()
    }
    /// Hand the server task over to the `sim serve` registry.
    pub fn into_endpoint(mut self, device: &str, protocol: &str) -> crate::serve::Endpoint {
        crate::serve::Endpoint {
            device: device.to_string(),
            protocol: protocol.to_string(),
            addr: self.addr,
            path: self.path.clone(),
            task: self.tasks.pop(),
        }
    }
    /// Every command word received so far.
    pub fn log(&self) -> Vec<String> {
        self.device
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .log
            .clone()
    }
}

fn new_device(source: Arc<dyn TrackerSource>, config: SimNdiConfig) -> Arc<Mutex<NdiDevice>> {
    Arc::new(Mutex::new(NdiDevice::new(source, config)))
}

/// Serve a Vega on `bind` (use port 0 for a free port); returns once listening.
pub async fn serve_tcp(
    source: Arc<dyn TrackerSource>,
    config: SimNdiConfig,
    bind: SocketAddr,
) -> std::io::Result<SimNdi> {
    let listener = tokio::net::TcpListener::bind(bind).await?;
    let addr = listener.local_addr()?;
    let device = new_device(source, config);
    let dev = device.clone();
    let task = tokio::spawn(async move {
        while let Ok((stream, _)) = listener.accept().await {
            let _ = stream.set_nodelay(true);
            let dev = dev.clone();
            tokio::spawn(async move {
                let _ = session(stream, dev).await;
            });
        }
    });
    Ok(SimNdi {
        addr: Some(addr),
        path: None,
        device,
        tasks: vec![task],
    })
}

/// Serve a serial Polaris on a new pty; the client opens [`SimNdi::path`].
pub fn serve_pty(source: Arc<dyn TrackerSource>, config: SimNdiConfig) -> std::io::Result<SimNdi> {
    use serialport::SerialPort as _;
    let (master, slave) = serialport::TTYPort::pair().map_err(std::io::Error::other)?;
    let path = slave
        .name()
        .ok_or_else(|| std::io::Error::other("pty without a name"))?;
    let master = tokio_serial::SerialStream::try_from(master).map_err(std::io::Error::other)?;
    let device = new_device(source, config);
    let dev = device.clone();
    let task = tokio::spawn(async move {
        // Keep the slave side open so the master never sees a hang-up between clients.
        let _slave = slave;
        let _ = session(master, dev).await;
    });
    Ok(SimNdi {
        addr: None,
        path: Some(path),
        device,
        tasks: vec![task],
    })
}

async fn session<S: AsyncRead + AsyncWrite + Unpin>(
    mut io: S,
    device: Arc<Mutex<NdiDevice>>,
) -> std::io::Result<()> {
    let mut buf: Vec<u8> = Vec::new();
    let mut scratch = [0u8; 4096];
    loop {
        let n = io.read(&mut scratch).await?;
        if n == 0 {
            return Ok(());
        }
        buf.extend_from_slice(&scratch[..n]);
        while let Some(pos) = buf.iter().position(|&b| b == b'\r') {
            let line: Vec<u8> = buf.drain(..=pos).take(pos).collect();
            // Tolerate a stray LF from hosts that send CRLF.
            let line = line.strip_prefix(b"\n").unwrap_or(&line).to_vec();
            let out = device
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .handle_line(&line);
            match out {
                Output::Send(bytes) | Output::SendThenBaud(bytes, _) => {
                    io.write_all(&bytes).await?;
                    io.flush().await?;
                }
                Output::Delayed(bytes, secs) => {
                    let clock = device.lock().unwrap_or_else(|e| e.into_inner()).clock();
                    match clock {
                        Some(c) => c.sleep(secs).await,
                        None if secs.is_finite() && secs > 0.0 => {
                            tokio::time::sleep(std::time::Duration::from_secs_f64(secs.min(3600.0)))
                                .await
                        }
                        None => {}
                    }
                    io.write_all(&bytes).await?;
                    io.flush().await?;
                }
                Output::Nothing => {}
                Output::Drop => return Ok(()),
            }
        }
        if buf.len() > MAX_COMMAND {
            buf.clear();
            io.write_all(&wire::error_reply(0x02)).await?;
        }
    }
}
