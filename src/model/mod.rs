//! model (filled by its issue).
