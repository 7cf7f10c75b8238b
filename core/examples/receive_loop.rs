//! A loop of `Arbiter::receive` calls for counting instructions per frame with callgrind, a
//! figure that, unlike a time, does not depend on what else the machine is doing:
//!
//!     scripts/instructions-per-frame.sh
//!
//! Usage: `receive_loop CASE FRAMES` with CASE one of walk-4, walk-16, walk-32, active-4,
//! active-16, active-32, full. Setup is the same for any FRAMES, so the difference between two
//! runs divided by the difference in frames is the cost of one frame.

#[path = "../benches/common/mod.rs"]
mod common;

use std::hint::black_box;

use pab_core::Instant;

fn main() {
    let mut args = std::env::args().skip(1);
    let (Some(case), Some(frames)) = (args.next(), args.next().and_then(|f| f.parse::<u64>().ok()))
    else {
        eprintln!(
            "usage: receive_loop CASE FRAMES (CASE: walk-4|walk-16|walk-32|active-4|active-16|active-32|full)"
        );
        std::process::exit(2);
    };
    let mut case = match case.as_str() {
        "walk-4" => common::longest_walk(4),
        "walk-16" => common::longest_walk(16),
        "walk-32" => common::longest_walk(32),
        "active-4" => common::all_active(4),
        "active-16" => common::all_active(16),
        "active-32" => common::all_active(32),
        "full" => common::full_capacity(),
        other => {
            eprintln!("unknown case {other}");
            std::process::exit(2);
        }
    };
    case.verify(Instant::from_micros(1));
    let mut now = Instant::from_micros(1);
    for _ in 0..frames {
        now = now.wrapping_add_micros(1);
        case.arbiter
            .receive(black_box(&case.id), black_box(now), |verdict| {
                black_box(verdict);
            });
    }
}
