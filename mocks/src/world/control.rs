//! Out-of-band control for tests: read the truth, inject faults. Never reachable through a wire.
//!
//! Wire faults are queued per device and consumed by the protocol servers with
//! [`Control::take_fault`] (one fault per call, first in first out). World faults (occlusion,
//! protective stop, out-of-range) change what the world itself reports.

use super::{World, WorldHandle};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// A fault a protocol server applies to its next reply (or to the link).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Fault {
    /// Close the connection (TCP reset / pty hang-up) instead of answering.
    DropLink,
    /// Answer, but only after `secs` seconds (of the world clock).
    Delay {
        /// Delay (s).
        secs: f64,
    },
    /// Answer with the protocol's error reply (`code` in the device's own numbering, e.g. a
    /// b-CAP HRESULT, an NDI `ERROR` code, a DL-RS1A `ER` code).
    ErrorReply {
        /// Device error code.
        code: i64,
    },
    /// Send these bytes instead of the reply.
    Garbage {
        /// The bytes.
        bytes: Vec<u8>,
    },
    /// Send the reply with a corrupted checksum / CRC.
    BadCrc,
    /// Send only the first half of the reply.
    Truncated,
    /// Send nothing for `secs` seconds (then continue normally).
    Silence {
        /// Silence (s).
        secs: f64,
    },
}

/// Out-of-band state kept by the world.
#[derive(Debug, Default)]
pub(crate) struct ControlState {
    pub(crate) faults: std::collections::HashMap<String, VecDeque<Fault>>,
}

/// Handle to inject faults and read the truth (tests only).
#[derive(Clone)]
pub struct Control {
    pub(crate) world: WorldHandle,
}

impl Control {
    fn with<R>(&self, f: impl FnOnce(&mut World) -> R) -> R {
        self.world.with(f)
    }

    /// Queue a wire fault for `device` (consumed by its protocol server).
    pub fn inject(&self, device: &str, fault: Fault) {
        self.with(|w| {
            w.control
                .faults
                .entry(device.to_string())
                .or_default()
                .push_back(fault)
        });
    }

    /// The next queued fault for `device`, if any (protocol servers call this before each reply).
    pub fn take_fault(&self, device: &str) -> Option<Fault> {
        self.with(|w| w.control.faults.get_mut(device).and_then(|q| q.pop_front()))
    }

    /// Number of faults still queued for `device`.
    pub fn pending_faults(&self, device: &str) -> usize {
        self.with(|w| w.control.faults.get(device).map_or(0, |q| q.len()))
    }

    /// Occlude (or un-occlude) the marker of tracker `tracker` (index).
    pub fn set_occluded(&self, tracker: usize, occluded: bool) {
        self.with(|w| {
            if let Some(t) = w.trackers.get_mut(tracker) {
                t.occluded = occluded;
            }
        });
    }

    /// Trigger a protective stop on arm `arm`: motion halts where it is.
    pub fn protective_stop(&self, arm: usize) {
        let now = self.world.now();
        self.with(|w| {
            if let Some(a) = w.arms.get_mut(arm) {
                a.halt(now);
                a.protective_stop = true;
            }
        });
    }

    /// Force the next `count` readings of laser `laser` to be out of range.
    pub fn force_out_of_range(&self, laser: usize, count: u32) {
        self.with(|w| {
            if let Some(l) = w.lasers.get_mut(laser) {
                l.force_oor = count;
            }
        });
    }

    /// The hidden truth.
    pub fn truth(&self) -> super::Truth {
        self.world.truth()
    }
}
