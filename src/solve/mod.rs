//! solve (filled by its issue).
