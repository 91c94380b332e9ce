//! Evaluation harnesses: trials that run the estimators on the simulators' output and score
//! them against the simulated truth. Truth is read here only to score; the estimators see
//! what a dataset holds.
pub mod rcm_images;
