//! Orbit, frames, sun, eclipse and geomagnetic field (filled by the orbit issue).
