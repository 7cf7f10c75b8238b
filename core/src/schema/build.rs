//! Schemas as the client's calls make them (the paper's API functions): one function per call,
//! shared by the Rust client, the simulator and the tests, so that every runner sends the same
//! schemas for the same program.
//!
//! Each schema's reactions end it into the queue when its action succeeds, and into the wait
//! for the high-priority channel when it fails in a way the client must decide about (a
//! touch-down that met nothing); the server's safety events come before them all.

use heapless::Vec;

use super::{Action, Event, Gripper, Measure, Pose, Reaction, Schema, Source};

fn schema(id: u16, action: Action, reactions: &[Reaction]) -> Schema {
    let mut r = Vec::new();
    for reaction in reactions {
        // At most three reactions here, capacity 16.
        let _ = r.push(*reaction);
    }
    Schema {
        id,
        action,
        reactions: r,
        watchdog_ms: 0,
    }
}

const fn on(event: Event, next: Source) -> Reaction {
    Reaction { event, next }
}

/// `moveTo(pose)`: the attractor to `goal` in a straight line at `speed` µm/s; the next queued
/// schema when it is there.
pub fn move_to(id: u16, goal: Pose, speed: u32) -> Schema {
    schema(
        id,
        Action::MoveTo { goal, speed },
        &[on(Event::Done, Source::Queue)],
    )
}

/// `moveToTouch(dir)`: along `direction` at `speed` until the contact force reaches `contact` mN
/// (then the next queued schema), at most `distance` µm (then the wait for the high-priority
/// channel: nothing was there).
pub fn move_to_touch(id: u16, direction: Pose, speed: u32, contact: i32, distance: u32) -> Schema {
    schema(
        id,
        Action::MoveToTouch {
            direction,
            speed,
            distance,
        },
        &[
            on(Event::Above(Measure::Contact, contact), Source::Queue),
            on(Event::Done, Source::HighPriority),
        ],
    )
}

/// `grasp()`: close the gripper and let it settle.
pub fn grasp(id: u16, settle_ms: u32) -> Schema {
    schema(
        id,
        Action::Grasp { settle_ms },
        &[on(Event::Done, Source::Queue)],
    )
}

/// `release()`: open the gripper and let it settle.
pub fn release(id: u16, settle_ms: u32) -> Schema {
    schema(
        id,
        Action::Release { settle_ms },
        &[on(Event::Done, Source::Queue)],
    )
}

/// `blind_search()`: the spiral under preload ([`Action::BlindSearch`]) until the measured z has
/// dropped `depth` µm below where it started (the part is in), then the next queued schema.
pub fn blind_search(id: u16, search: Action, depth: u32) -> Schema {
    let depth = i32::try_from(depth).unwrap_or(i32::MAX);
    schema(
        id,
        search,
        &[on(
            Event::Below(Measure::Displacement(2), -depth),
            Source::Queue,
        )],
    )
}

/// `idle(ms)`: hold the command for `ms`, then the next queued schema.
pub fn idle(id: u16, ms: u32) -> Schema {
    schema(id, Action::Idle { ms }, &[on(Event::Done, Source::Queue)])
}

/// An atomic action (gripper, impedance, relieve), then the next queued schema at one-shot.
pub fn atomic(id: u16, action: Action) -> Schema {
    schema(id, action, &[on(Event::OneShot, Source::Queue)])
}

/// Open or close the gripper at once.
pub fn gripper(id: u16, g: Gripper) -> Schema {
    atomic(id, Action::Gripper(g))
}
