//! RTDE (Real-Time Data Exchange, TCP 30004): frame / codec / client.

pub mod client;
pub mod codec;
pub mod frame;

pub use client::{RtdeClient, RtdeConfig, RtdeSample, ARM_OUTPUTS};
pub use frame::{ControllerVersion, DataType, Reply, Request, RobotMode, SafetyMode, Value};
