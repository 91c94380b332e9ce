//! diagnose (filled by its issue).
