//! Safety and time parameters given on the command line or in a file: a speed or
//! acceleration cap must be finite, positive and never above the cell's own limit; a timeout
//! must be finite and positive. A cap of 0, a negative or a NaN cap would otherwise remove
//! the cap (or make every move fail) without an error.

/// A cell's own motion limit and where it comes from.
#[derive(Debug, Clone, PartialEq)]
pub struct CellLimit {
    /// The limit (same unit as the cap).
    pub value: f64,
    /// Where it comes from (`scenario lab.toml, arm "vs060" motion.max_vel_deg_s`).
    pub source: String,
}

/// Checks a motion cap `value` given as `flag` (unit `unit`) against the cell's limit.
pub fn motion_cap(
    flag: &str,
    value: f64,
    unit: &str,
    cell: Option<&CellLimit>,
) -> Result<f64, String> {
    if !value.is_finite() || value <= 0.0 {
        return Err(format!(
            "{flag} {value}: a {unit} cap must be a finite number > 0 (0, negative or NaN would \
             remove the cap or stop every move)"
        ));
    }
    if let Some(c) = cell {
        if c.value.is_finite() && c.value > 0.0 && value > c.value * (1.0 + 1e-9) {
            return Err(format!(
                "{flag} {value} {unit} is above the cell's limit of {} {unit} ({}): give at most \
                 {}",
                c.value, c.source, c.value
            ));
        }
    }
    Ok(value)
}

/// Checks a duration in seconds given as `flag`: finite, > 0 and at most `max_s`.
pub fn seconds(flag: &str, value: f64, max_s: f64) -> Result<std::time::Duration, String> {
    if !value.is_finite() || value <= 0.0 || value > max_s {
        return Err(format!(
            "{flag} {value}: a timeout must be a finite number of seconds in (0, {max_s}]"
        ));
    }
    Ok(std::time::Duration::from_secs_f64(value))
}

/// Most bootstrap refits a command runs (each is a whole fit): 100 000.
pub const MAX_BOOTSTRAP: usize = 100_000;

/// Checks a count given as `flag` against its cap (bounded time and memory on any input).
pub fn count(flag: &str, value: usize, max: usize, what: &str) -> Result<usize, String> {
    if value > max {
        return Err(format!(
            "{flag} {value}: at most {max} {what} (each is a whole fit; more would run for days \
             or exhaust memory without changing the result)"
        ));
    }
    Ok(value)
}

/// [`count`] for a `--bootstrap` option, as an `anyhow` error.
pub fn bootstrap(value: usize) -> anyhow::Result<usize> {
    count("--bootstrap", value, MAX_BOOTSTRAP, "bootstrap refits").map_err(anyhow::Error::msg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caps_must_be_finite_positive_and_below_the_cell() {
        let cell = CellLimit {
            value: 180.0,
            source: "scenario".into(),
        };
        for v in [0.0, -5.0, f64::NAN, f64::INFINITY] {
            let e = motion_cap("--speed-deg-s", v, "deg/s", Some(&cell)).unwrap_err();
            assert!(e.contains("--speed-deg-s"), "{e}");
        }
        let e = motion_cap("--speed-deg-s", 181.0, "deg/s", Some(&cell)).unwrap_err();
        assert!(e.contains("cell's limit of 180"), "{e}");
        assert_eq!(
            motion_cap("--speed-deg-s", 60.0, "deg/s", Some(&cell)),
            Ok(60.0)
        );
        assert!(seconds("--timeout-s", f64::NAN, 600.0).is_err());
        assert!(seconds("--timeout-s", 0.0, 600.0).is_err());
        assert!(seconds("--timeout-s", 5.0, 600.0).is_ok());
        let e = count("--bootstrap", 100_000_000, MAX_BOOTSTRAP, "refits").unwrap_err();
        assert!(
            e.contains("--bootstrap 100000000") && e.contains("at most 100000"),
            "{e}"
        );
        assert_eq!(count("--bootstrap", 200, MAX_BOOTSTRAP, "refits"), Ok(200));
    }
}
