//! Virtual time: every wait jumps the clock instead of sleeping.

use async_trait::async_trait;
use robocal_drivers::Clock;
use std::sync::Mutex;

/// A simulated clock (s). `sleep` advances it instantly, so a 600-pose session takes seconds of
/// wall time and is deterministic.
#[derive(Debug, Default)]
pub struct VirtualClock {
    t: Mutex<f64>,
}

impl VirtualClock {
    /// A clock at t = 0.
    pub fn new() -> Self {
        Self::default()
    }
    /// Advance by `secs` (ignored when negative or not finite).
    pub fn advance(&self, secs: f64) {
        if secs > 0.0 && secs.is_finite() {
            *self.t.lock().unwrap_or_else(|e| e.into_inner()) += secs;
        }
    }
    /// Advance to `t` if it lies in the future.
    pub fn advance_to(&self, t: f64) {
        let mut g = self.t.lock().unwrap_or_else(|e| e.into_inner());
        if t > *g && t.is_finite() {
            *g = t;
        }
    }
}

#[async_trait]
impl Clock for VirtualClock {
    fn now(&self) -> f64 {
        *self.t.lock().unwrap_or_else(|e| e.into_inner())
    }
    async fn sleep(&self, secs: f64) {
        self.advance(secs);
        tokio::task::yield_now().await;
    }
}
