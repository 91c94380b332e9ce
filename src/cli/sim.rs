//! `robocal sim`: run the simulated devices of a scenario (thin; the work is in
//! `crate::cell::simulated::serve`, built with the feature `sim`).

#[cfg(feature = "sim")]
use anyhow::Context as _;
#[cfg(feature = "sim")]
use std::io::Write as _;
use std::path::PathBuf;

/// Arguments of `robocal sim`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: SimCommand,
}

/// `robocal sim` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum SimCommand {
    /// Serve every device of a scenario over its real wire protocol until killed. Prints one JSON
    /// line per endpoint, then `{"ready": true}`.
    Serve(ServeArgs),
}

/// Arguments of `robocal sim serve`.
#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Scenario file (TOML, see `mocks/scenarios/`).
    #[arg(long)]
    pub scenario: PathBuf,
    /// Address to bind (e.g. 127.0.0.2 to give a simulated controller its own IP).
    #[arg(long, default_value = "127.0.0.1")]
    pub host: std::net::IpAddr,
    /// Bind the vendors' fixed ports (RTDE 30004, dashboard 29999, script 30001–30003,
    /// b-CAP 5007, NDI 8765) instead of free ports.
    #[arg(long)]
    pub standard_ports: bool,
    /// Run on virtual time (every wait jumps) instead of the wall clock.
    #[arg(long)]
    pub virtual_clock: bool,
}

/// Run `robocal sim`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    match args.command {
        SimCommand::Serve(a) => serve(a),
    }
}

#[cfg(not(feature = "sim"))]
fn serve(a: ServeArgs) -> anyhow::Result<()> {
    Err(crate::cell::without_simulators(&format!(
        "sim serve --scenario {}",
        a.scenario.display()
    )))
}

#[cfg(feature = "sim")]
fn serve(a: ServeArgs) -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(async move {
        let served =
            crate::cell::simulated::serve(&a.scenario, a.host, a.standard_ports, a.virtual_clock)
                .await?;
        let mut out = std::io::stdout().lock();
        for line in served.json_lines() {
            writeln!(out, "{line}")?;
        }
        writeln!(out, "{}", serde_json::json!({"ready": true}))?;
        out.flush()?;
        drop(out);
        tokio::signal::ctrl_c().await?;
        served.abort();
        Ok(())
    })
}
