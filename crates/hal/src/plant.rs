//! Plants the host can drive (being written).
