//! The one validation of a device file for use (one check for every path): what `robocal
//! devices` (listing and `--probe`), `robocal run --devices` and `robocal session --devices`
//! check before any device is opened or any consent is asked.
//!
//! Beyond the strict format ([`DevicesFile::read`]): the file itself must be a regular file;
//! every network address must parse (`192.168.0.300` is not an IPv4 address, a port is
//! 1–65535); an NDI tracker needs its tool definition files (`tools = ["probe.rom"]`,
//! resolved against the **device file's** folder), each present, a regular file, readable,
//! of a tool definition's size and starting with NDI's `NDI` signature.
//!
//! A session or a run copies the device file into its directory: [`resolved_toml`] writes
//! that copy with the tool paths made absolute, so the copy loads the same files as the
//! original wherever it lies.
use std::path::{Path, PathBuf};

use super::devices::{DeviceEntry, DevicesFile, Protocol};

/// The largest tool definition accepted (NDI's tool `.rom` images are 752 bytes; the
/// driver's upload refuses more than 64 KiB).
pub const ROM_MAX_BYTES: u64 = 64 * 1024;
/// The smallest: the signature, the checksum and the header.
pub const ROM_MIN_BYTES: u64 = 64;

/// One problem of one device (or of the file, `device` = `None`).
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// The device's name.
    pub device: Option<String>,
    /// What is wrong and the likely cause.
    pub message: String,
}

/// A tool definition read from disk: its name (file stem), resolved path and bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolRom {
    pub name: String,
    pub path: PathBuf,
    pub bytes: Vec<u8>,
}

/// A device file checked for use: the parsed file, its folder, and the problems found
/// (empty = ready to probe / connect).
#[derive(Debug, Clone)]
pub struct CheckedDevices {
    pub path: PathBuf,
    pub file: DevicesFile,
    /// The device file's folder: relative `tools` and `path` entries are resolved against it.
    pub base: PathBuf,
    pub problems: Vec<Problem>,
}

impl CheckedDevices {
    /// The problems of device `name`.
    pub fn problems_of<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Problem> + 'a {
        self.problems
            .iter()
            .filter(move |p| p.device.as_deref() == Some(name))
    }

    /// `Ok` when nothing is wrong, else one error listing every problem (file and device
    /// named) — the form `run` and `session` refuse a device file in, before any consent.
    pub fn require_valid(&self) -> anyhow::Result<()> {
        if self.problems.is_empty() {
            return Ok(());
        }
        let mut msg = format!(
            "{}: the device file is not ready for use ({} problem{}):",
            self.path.display(),
            self.problems.len(),
            if self.problems.len() == 1 { "" } else { "s" }
        );
        for p in &self.problems {
            match &p.device {
                Some(d) => msg += &format!("\n  device {d:?}: {}", p.message),
                None => msg += &format!("\n  {}", p.message),
            }
        }
        msg += "\nnothing was opened and nothing moved";
        Err(anyhow::Error::msg(msg))
    }
}

/// Reads `path` strictly and checks every device for use. A file that cannot be read or
/// parsed is an error; problems of single devices are collected in
/// [`CheckedDevices::problems`].
pub fn check_file(path: &Path) -> anyhow::Result<CheckedDevices> {
    match std::fs::metadata(path) {
        Err(e) => anyhow::bail!(
            "{}: cannot read the device file: {}",
            path.display(),
            os_error(&e)
        ),
        Ok(m) if m.is_dir() => anyhow::bail!(
            "{}: is a directory, not a device file (give the CELL.toml inside it)",
            path.display()
        ),
        Ok(m) if !m.is_file() => anyhow::bail!(
            "{}: not a regular file (a device, FIFO or socket): give the CELL.toml file",
            path.display()
        ),
        Ok(m) if m.len() > 1 << 20 => anyhow::bail!(
            "{}: {} bytes is not a device file (a few KiB of TOML): wrong file?",
            path.display(),
            m.len()
        ),
        Ok(_) => {}
    }
    let file = DevicesFile::read(path)?;
    let base = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let mut problems = Vec::new();
    for d in &file.devices {
        for message in check_device(d, &base) {
            problems.push(Problem {
                device: Some(d.name.clone()),
                message,
            });
        }
    }
    Ok(CheckedDevices {
        path: path.to_path_buf(),
        file,
        base,
        problems,
    })
}

/// The OS error without Rust's `(os error N)` suffix repeated by callers.
fn os_error(e: &std::io::Error) -> String {
    let s = e.to_string();
    match s.find(" (os error") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}

fn check_device(d: &DeviceEntry, base: &Path) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(a) = &d.address {
        match d.protocol {
            Protocol::Bcap | Protocol::NdiTcp => {
                if let Err(e) = check_host_port(a, true) {
                    out.push(format!("address = {a:?}: {e}"));
                }
            }
            Protocol::Rtde => {
                if let Err(e) = check_host_port(a, false) {
                    out.push(format!("address = {a:?}: {e}"));
                }
            }
            _ => {}
        }
    }
    if let (Some(port), Protocol::NdiSerial | Protocol::DlRs1a) = (&d.serial, d.protocol) {
        if let Err(e) = check_serial(port) {
            out.push(e);
        }
    }
    if matches!(d.protocol, Protocol::NdiTcp | Protocol::NdiSerial) {
        if d.tools.is_empty() {
            out.push(
                "an NDI tracker needs the tool definition of the marker it tracks: add \
                 `tools = [\"marker.rom\"]` (the .rom file from NDI's tool software, relative \
                 to this device file)"
                    .into(),
            );
        }
        for t in &d.tools {
            if let Err(e) = read_rom(base, t) {
                out.push(e);
            }
        }
    } else if !d.tools.is_empty() {
        out.push(format!(
            "`tools` is for NDI trackers (protocol ndi-tcp / ndi-serial), not {:?}",
            d.protocol
        ));
    }
    out
}

/// The serial ports this machine has (USB adapters and by-id names), for messages.
pub fn serial_ports() -> Vec<String> {
    let mut v = Vec::new();
    if let Ok(rd) = std::fs::read_dir("/dev/serial/by-id") {
        v.extend(rd.flatten().map(|e| e.path().display().to_string()));
    }
    if let Ok(rd) = std::fs::read_dir("/dev") {
        v.extend(
            rd.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with("ttyUSB") || n.starts_with("ttyACM"))
                .map(|n| format!("/dev/{n}")),
        );
    }
    v.sort();
    v
}

/// A serial port named in the file must exist (a pty path from the simulator counts).
fn check_serial(port: &str) -> Result<(), String> {
    match std::fs::metadata(port) {
        Ok(m) if m.is_dir() => Err(format!(
            "serial = {port:?}: is a directory, not a serial port"
        )),
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let ports = serial_ports();
            Err(format!(
                "serial = {port:?}: no such device: is the USB–serial adapter plugged in? \
                 ports present: {}",
                if ports.is_empty() {
                    "none".to_string()
                } else {
                    ports.join(", ")
                }
            ))
        }
        Err(e) => Err(format!("serial = {port:?}: {}", os_error(&e))),
    }
}

/// Resolves a `tools` entry against the device file's folder.
pub fn resolve(base: &Path, entry: &str) -> PathBuf {
    let p = Path::new(entry);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    }
}

/// Reads and checks one tool definition (`entry` as written in the file).
pub fn read_rom(base: &Path, entry: &str) -> Result<ToolRom, String> {
    let path = resolve(base, entry);
    let shown = format!("tools entry {entry:?} ({})", path.display());
    let meta = std::fs::metadata(&path).map_err(|e| {
        format!(
            "{shown}: {}; tool files are resolved against the device file's folder {}",
            os_error(&e),
            base.display()
        )
    })?;
    if meta.is_dir() {
        return Err(format!(
            "{shown}: is a directory, not a tool definition (.rom) file"
        ));
    }
    if !meta.is_file() {
        return Err(format!(
            "{shown}: not a regular file (device, FIFO or socket)"
        ));
    }
    let n = meta.len();
    if !(ROM_MIN_BYTES..=ROM_MAX_BYTES).contains(&n) {
        return Err(format!(
            "{shown}: {n} bytes is not an NDI tool definition ({ROM_MIN_BYTES} B – 64 KiB; \
             NDI's .rom files are 752 bytes): wrong file?"
        ));
    }
    let bytes = std::fs::read(&path).map_err(|e| format!("{shown}: {}", os_error(&e)))?;
    if !bytes.starts_with(b"NDI") {
        return Err(format!(
            "{shown}: does not start with NDI's signature \"NDI\": not a tool definition \
             (.rom) file (export it from NDI's tool software)"
        ));
    }
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| entry.to_string());
    Ok(ToolRom { name, path, bytes })
}

/// The tool definitions of an NDI tracker entry, read and checked.
pub fn tool_roms(d: &DeviceEntry, base: &Path) -> anyhow::Result<Vec<ToolRom>> {
    if d.tools.is_empty() {
        anyhow::bail!(
            "device {:?}: an NDI tracker needs at least one tool definition (`tools = \
             [\"probe.rom\"]`)",
            d.name
        );
    }
    d.tools
        .iter()
        .map(|t| read_rom(base, t).map_err(|e| anyhow::anyhow!("device {:?}: {e}", d.name)))
        .collect()
}

/// Checks `host:port` (`need_port`) or `host[:port]`: an IPv4 address whose four numbers
/// are 0–255, a bracketed IPv6 address, or a host name; a port 1–65535.
pub fn check_host_port(addr: &str, need_port: bool) -> Result<(), String> {
    let a = addr.trim();
    if a != addr || a.is_empty() {
        return Err("spaces around the address, or empty".into());
    }
    let (host, port) = if let Some(rest) = a.strip_prefix('[') {
        let (h, tail) = rest
            .split_once(']')
            .ok_or("an IPv6 address in brackets needs its closing `]`")?;
        h.parse::<std::net::Ipv6Addr>()
            .map_err(|_| format!("[{h}] is not an IPv6 address"))?;
        match tail.strip_prefix(':') {
            Some(p) => (None, Some(p)),
            None if tail.is_empty() => (None, None),
            None => return Err(format!("unexpected {tail:?} after the IPv6 address")),
        }
    } else {
        match a.rsplit_once(':') {
            Some((h, p)) => (Some(h), Some(p)),
            None => (Some(a), None),
        }
    };
    if let Some(h) = host {
        check_host(h)?;
    }
    match port {
        None if need_port => {
            return Err("give host:port (e.g. 192.168.0.1:5007)".into());
        }
        None => {}
        Some(p) => match p.parse::<u16>() {
            Ok(n) if n > 0 => {}
            _ => return Err(format!("port {p:?} is not a port number (1–65535)")),
        },
    }
    Ok(())
}

fn check_host(h: &str) -> Result<(), String> {
    if h.is_empty() {
        return Err("no host before the port".into());
    }
    if h.chars().all(|c| c.is_ascii_digit() || c == '.') {
        return h.parse::<std::net::Ipv4Addr>().map(|_| ()).map_err(|_| {
            format!(
                "{h} is not an IPv4 address (four numbers 0–255 separated by dots): a typo in \
                 the address?"
            )
        });
    }
    if h.contains(':') {
        return Err(format!(
            "{h}: an IPv6 address goes in brackets ([{h}]:port)"
        ));
    }
    let ok_label = |l: &str| {
        !l.is_empty()
            && l.len() <= 63
            && !l.starts_with('-')
            && !l.ends_with('-')
            && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
    };
    if h.len() > 253 || !h.trim_end_matches('.').split('.').all(ok_label) {
        return Err(format!(
            "{h:?} is neither an IPv4 address nor a host name (letters, digits, `-` and `.`)"
        ));
    }
    Ok(())
}

/// The device file as TOML with every `tools` entry (and a `pgm-folder` camera's `path`)
/// made absolute against `base`: what a session / run directory keeps as its copy, so the
/// copy resolves to the same files as the original.
pub fn resolved_toml(file: &DevicesFile, base: &Path) -> anyhow::Result<String> {
    let abs_base = std::path::absolute(base).unwrap_or_else(|_| base.to_path_buf());
    let mut f = file.clone();
    for d in &mut f.devices {
        for t in &mut d.tools {
            *t = resolve(&abs_base, t).to_string_lossy().into_owned();
        }
        if d.protocol == Protocol::PgmFolder {
            if let Some(p) = &mut d.path {
                *p = resolve(&abs_base, p).to_string_lossy().into_owned();
            }
        }
    }
    Ok(format!(
        "# The device file as this session / run used it (`tools` and image folders resolved \
         against the original's folder {}).\n{}",
        abs_base.display(),
        toml::to_string(&f)?
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses() {
        for ok in [
            "192.168.0.1:5007",
            "localhost:8765",
            "rc8.cell.local:5007",
            "[::1]:5007",
        ] {
            assert!(check_host_port(ok, true).is_ok(), "{ok}");
        }
        assert!(check_host_port("10.0.0.9", false).is_ok());
        for (bad, want) in [
            ("192.168.0.300:5007", "not an IPv4 address"),
            ("192.168.0:5007", "not an IPv4 address"),
            ("192.168.0.1:0", "port"),
            ("192.168.0.1:70000", "port"),
            ("192.168.0.1:http", "port"),
            (":5007", "no host"),
            ("host_name:5007", "neither"),
            ("192.168.0.1", "host:port"),
            ("::1:5007", "brackets"),
        ] {
            let e = check_host_port(bad, true).unwrap_err();
            assert!(e.contains(want), "{bad}: {e}");
        }
    }

    fn rom_file(dir: &Path, name: &str, bytes: &[u8]) {
        std::fs::write(dir.join(name), bytes).unwrap();
    }

    #[test]
    fn tools_resolved_against_the_device_files_folder() {
        let tmp = tempfile::tempdir().unwrap();
        let cell = tmp.path().join("cell");
        std::fs::create_dir_all(cell.join("tools")).unwrap();
        let mut good = b"NDI\0".to_vec();
        good.resize(752, 7);
        rom_file(&cell.join("tools"), "probe.rom", &good);
        rom_file(&cell, "garbage.rom", &[0x55; 752]);
        rom_file(&cell, "empty.rom", &[]);
        std::fs::create_dir_all(cell.join("dir.rom")).unwrap();
        let text = |tools: &str| {
            format!(
                "[[device]]\nname = \"vega\"\nrole = \"tracker\"\nvendor = \"ndi\"\n\
                 protocol = \"ndi-tcp\"\naddress = \"127.0.0.1:8765\"\n{tools}\n"
            )
        };
        let path = cell.join("CELL.toml");
        let check = |tools: &str| {
            std::fs::write(&path, text(tools)).unwrap();
            check_file(&path).unwrap()
        };
        let c = check("tools = [\"tools/probe.rom\"]");
        assert!(c.problems.is_empty(), "{:?}", c.problems);
        // The copy a session keeps resolves to the same file from anywhere.
        let copy = tmp.path().join("elsewhere/devices.toml");
        std::fs::create_dir_all(copy.parent().unwrap()).unwrap();
        std::fs::write(&copy, resolved_toml(&c.file, &c.base).unwrap()).unwrap();
        let c2 = check_file(&copy).unwrap();
        assert!(c2.problems.is_empty(), "{:?}", c2.problems);
        let roms = tool_roms(&c2.file.devices[0], &c2.base).unwrap();
        assert_eq!(roms[0].bytes, good);
        assert_eq!(roms[0].name, "probe");
        for (tools, want) in [
            ("", "needs the tool definition"),
            ("tools = [\"missing.rom\"]", "No such file"),
            ("tools = [\"dir.rom\"]", "is a directory"),
            ("tools = [\"garbage.rom\"]", "signature"),
            ("tools = [\"empty.rom\"]", "0 bytes"),
        ] {
            let c = check(tools);
            let e = c.require_valid().unwrap_err().to_string();
            assert!(e.contains(want) && e.contains("vega"), "{tools}: {e}");
            assert_eq!(c.problems_of("vega").count(), 1);
        }
        // A 200 MB file is refused by its size, without reading it.
        let big = std::fs::File::create(cell.join("big.rom")).unwrap();
        big.set_len(200 << 20).unwrap();
        let e = check("tools = [\"big.rom\"]")
            .require_valid()
            .unwrap_err()
            .to_string();
        assert!(e.contains("209715200 bytes"), "{e}");
        // The device file itself: a directory is named as such.
        let e = check_file(&cell).unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
    }
}
