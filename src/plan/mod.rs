//! plan (filled by its issue).
