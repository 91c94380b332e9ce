//! acquire (filled by its issue).
