//! What this board does with delivered frames: logs and counts them. A real board puts its
//! actuators here, in its [`pab_app::Recipient::deliver`] (below).

use pab_core::{Frame, Instant};

/// Counts the frames delivered at each port and logs each one (defmt, debug level).
pub struct BoardRecipient {
    delivered: [u32; pab_core::BOARD_PORTS],
}

impl BoardRecipient {
    /// Nothing delivered yet.
    pub const fn new() -> Self {
        BoardRecipient {
            delivered: [0; pab_core::BOARD_PORTS],
        }
    }
}

impl pab_app::Recipient for BoardRecipient {
    fn deliver(&mut self, port: u8, frame: &Frame, now: Instant) {
        let count = match self.delivered.get_mut(usize::from(port)) {
            Some(count) => {
                *count = count.wrapping_add(1);
                *count
            }
            None => 0,
        };
        let (id, extended) = frame.raw_id();
        defmt::debug!(
            "port {}: delivered id {=u32:#x}{} {=[u8]:02x} at {} us (#{})",
            port,
            id,
            if extended { " (ext)" } else { "" },
            frame.payload(),
            now.as_micros(),
            count
        );
        // A motor loop plugs in here: decode the winning command (it is the frame the table let
        // through for this port) and hand it to the control task, without blocking, e.g.
        //     MOTOR_SETPOINT.signal(decode(frame));
        // with `static MOTOR_SETPOINT: embassy_sync::signal::Signal<CriticalSectionRawMutex, _>`
        // awaited by a `#[embassy_executor::task]` that runs the loop. `deliver` is called from
        // the node task, so it must return quickly: the next frame waits for it.
    }
}
