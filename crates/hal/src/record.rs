//! Measured records on disk (being written).
