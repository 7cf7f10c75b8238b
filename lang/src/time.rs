//! Time as the network file writes it (seconds, `f64`) and as the boards and the simulator count
//! it (whole µs, `u64`): the one conversion each way, shared by the model, the simulator and the
//! tools so that a time in a file lands on the same microsecond everywhere.

/// Seconds to µs, rounded to the nearest microsecond.
pub fn micros(seconds: f64) -> u64 {
    (seconds * 1e6).round().max(0.0) as u64
}

/// `t` µs as seconds with six decimals, exactly.
pub fn seconds_text(t_us: u64) -> String {
    format!("{}.{:06}", t_us / 1_000_000, t_us % 1_000_000)
}
