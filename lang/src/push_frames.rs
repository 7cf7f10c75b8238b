//! What pushing a table image costs the bus: its ISO-TP transfer's frames, classic or on CAN FD,
//! and how long they occupy the bus back to back.
//!
//! The frames are the real ones: the image goes through pab-core's ISO-TP sender (the tool's,
//! `Sender` for classic CAN, `FdSender` at TX_DL 64 for CAN FD, as `pabctl push --fd` sends it)
//! into pab-core's receiver with the node's flow-control settings (`pab_app::Config`: a flow
//! control every 8 consecutive frames), and each frame's time is its actual bits with their
//! actual stuffing ([`crate::can_frame::transmitted`]) and the intermission. What it leaves out:
//! the time a node and the tool take to answer (a flow control's turnaround; the HIL suite
//! measures whole pushes), the TransferStatus that ends a push, a keyed node's TransferOpen and
//! receipt, and other traffic. A lower bound of a push's time on an otherwise idle bus, and the
//! exact count of its frames.

use pab_core::isotp::fd::TxDl;
use pab_core::isotp::{FdSender, Receiver, RxEvent, Sender, TxConfig, TxEvent};
use pab_core::protocol::{FrameId, Service, TOOL};
use pab_core::{Frame, Instant};

use crate::can_frame::{TimeBase, transmitted};
use crate::network::Network;

/// The largest image a node takes (a board's 8 KiB transfer buffer and the Linux node's alike are
/// at most this; a larger one is not pushed).
const MAX_IMAGE: usize = 16 * 1024;

/// One push's frames on the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PushFrames {
    /// The tool's frames: single, first and consecutive frames.
    pub frames: usize,
    /// The node's flow controls.
    pub flow_controls: usize,
    /// Their time on the bus back to back, intermissions included, in the units of the
    /// [`TimeBase`] they were counted on.
    pub units: u64,
}

impl PushFrames {
    /// The bus time in seconds.
    pub fn seconds(&self, base: &TimeBase) -> f64 {
        self.units as f64 / base.per_second as f64
    }
}

/// The frames of pushing `image` to node `node_id`: classic ISO-TP when `fd` is `false`, ISO-TP on
/// CAN FD at TX_DL 64 with bit-rate switching when `true`; timed on `base`. `Err` says why the
/// transfer could not complete (an image no node takes, a node id out of range).
pub fn push_frames(
    image: &[u8],
    node_id: u8,
    fd: bool,
    base: &TimeBase,
) -> Result<PushFrames, String> {
    if image.len() > MAX_IMAGE {
        return Err(format!(
            "{} bytes: larger than any node takes ({MAX_IMAGE})",
            image.len()
        ));
    }
    let config = pab_app::Config::new(node_id).map_err(|error| error.to_string())?;
    let to_node = FrameId::new(Service::TableTransfer, TOOL, node_id).id();
    let to_tool = FrameId::new(Service::TableTransfer, node_id, TOOL).id();
    let mut receiver = Box::new(Receiver::<MAX_IMAGE>::new(config.isotp));
    let mut sender = if fd {
        Segmenter::Fd(
            FdSender::new(image, TxConfig::default(), TxDl::MAX).map_err(|e| e.to_string())?,
        )
    } else {
        Segmenter::Classic(Sender::new(image, TxConfig::default()).map_err(|e| e.to_string())?)
    };
    let now = Instant::from_micros(0);
    let mut push = PushFrames {
        frames: 0,
        flow_controls: 0,
        units: 0,
    };
    // Each frame handed out is received at once; a transfer of N bytes takes fewer than N
    // frames and flow controls, so the bound only stops a state machine that would not end.
    for _ in 0..=2 * MAX_IMAGE {
        let data = match sender.poll(now) {
            Polled::Send(data) => data,
            Polled::Done => return Ok(push),
            Polled::Stalled(why) => return Err(why),
        };
        let frame = if fd {
            Frame::fd(to_node, &data, true)
        } else {
            Frame::data(to_node, &data)
        }
        .ok_or("a frame longer than its kind takes")?;
        push.frames += 1;
        push.units += transmitted(&frame).time(base);
        let outcome = if fd {
            receiver.on_fd_frame(&data, now)
        } else {
            receiver.on_frame(&data, now)
        };
        let flow_control = match outcome.event {
            RxEvent::SendFlowControl(bytes) => bytes,
            RxEvent::Nothing | RxEvent::Complete(_) => continue,
            other => return Err(format!("the node's receiver answered {other:?}")),
        };
        // The node answers in its transfer's kind: an 8-byte CAN FD frame to a CAN FD transfer.
        let answer = if fd {
            Frame::fd(to_tool, &flow_control, true)
        } else {
            Frame::data(to_tool, &flow_control)
        }
        .ok_or("a flow control longer than its kind takes")?;
        push.flow_controls += 1;
        push.units += transmitted(&answer).time(base);
        sender.on_flow_control(&flow_control, now);
    }
    Err("the transfer did not end".into())
}

/// The tool's sender of either kind.
enum Segmenter<'a> {
    Classic(Sender<'a>),
    Fd(FdSender<'a>),
}

/// What the sender does next.
enum Polled {
    Send(Vec<u8>),
    Done,
    Stalled(String),
}

impl Segmenter<'_> {
    fn poll(&mut self, now: Instant) -> Polled {
        match self {
            Segmenter::Classic(sender) => polled(sender.poll(now), |frame| frame.to_vec()),
            Segmenter::Fd(sender) => polled(sender.poll(now), |frame| frame.as_bytes().to_vec()),
        }
    }

    fn on_flow_control(&mut self, data: &[u8], now: Instant) {
        match self {
            Segmenter::Classic(sender) => {
                let _ = sender.on_flow_control(data, now);
            }
            Segmenter::Fd(sender) => {
                let _ = sender.on_flow_control(data, now);
            }
        }
    }
}

fn polled<F>(event: TxEvent<F>, bytes: impl Fn(&F) -> Vec<u8>) -> Polled {
    match event {
        TxEvent::Send(frame) => Polled::Send(bytes(&frame)),
        TxEvent::Done => Polled::Done,
        // Waiting without a flow control to come: the receiver gave none.
        TxEvent::WaitUntil(_) => Polled::Stalled("the sender waits for a flow control".into()),
        TxEvent::Failed(error) => Polled::Stalled(format!("the sender failed: {error:?}")),
    }
}

/// The bit rates a push's frames are timed at: the network's `[bus]` (classic CAN at its
/// `bitrate`; CAN FD at its `data_bitrate`), or without one 500 kbit/s and a 2 Mbit/s data phase,
/// the G474's rates. On a classic bus, CAN FD is timed at its `bitrate` and 2 Mbit/s (or the
/// nominal rate, if faster): what the same push would take with CAN FD nodes.
pub struct PushRates {
    /// Nominal, bit/s.
    pub bitrate: u32,
    /// CAN FD's data phase, bit/s.
    pub data_bitrate: u32,
    /// Whether the network says these (`[bus]`), or they are the defaults.
    pub from_network: bool,
}

/// One node's push, classic and CAN FD.
pub struct Push {
    /// Classic ISO-TP at the nominal rate.
    pub classic: PushFrames,
    /// ISO-TP on CAN FD (TX_DL 64, bit-rate switching).
    pub fd: PushFrames,
}

impl PushRates {
    const DEFAULT_BITRATE: u32 = 500_000;
    const DEFAULT_DATA_BITRATE: u32 = 2_000_000;

    pub fn of(network: &Network) -> PushRates {
        match &network.bus {
            Some(bus) => PushRates {
                bitrate: bus.bitrate,
                data_bitrate: bus
                    .data_bitrate
                    .unwrap_or(Self::DEFAULT_DATA_BITRATE.max(bus.bitrate)),
                from_network: true,
            },
            None => PushRates {
                bitrate: Self::DEFAULT_BITRATE,
                data_bitrate: Self::DEFAULT_DATA_BITRATE,
                from_network: false,
            },
        }
    }

    /// Classic CAN's time base at the nominal rate.
    pub fn classic_base(&self) -> TimeBase {
        TimeBase::new(self.bitrate, None)
    }

    /// CAN FD's time base, the data phase at `data_bitrate`.
    pub fn fd_base(&self) -> TimeBase {
        TimeBase::new(self.bitrate, Some(self.data_bitrate))
    }

    /// The push of `image` to node `node_id`, both ways.
    pub fn push(&self, image: &[u8], node_id: u8) -> Result<Push, String> {
        Ok(Push {
            classic: push_frames(image, node_id, false, &self.classic_base())?,
            fd: push_frames(image, node_id, true, &self.fd_base())?,
        })
    }

    /// What `pabctl compile` prints: `push: 28 classic CAN frames + 4 flow controls, 7.53 ms of
    /// bus at 500 kbit/s; CAN FD: ...`.
    pub fn describe(&self, push: &Push) -> String {
        let frames = |p: &PushFrames, kind: &str| {
            format!(
                "{} {kind}frame{} + {} flow control{}",
                p.frames,
                if p.frames == 1 { "" } else { "s" },
                p.flow_controls,
                if p.flow_controls == 1 { "" } else { "s" }
            )
        };
        format!(
            "push: {}, {:.2} ms of bus at {}; CAN FD: {}, {:.2} ms at {} / {}{}",
            frames(&push.classic, "classic CAN "),
            push.classic.seconds(&self.classic_base()) * 1e3,
            rate(self.bitrate),
            frames(&push.fd, ""),
            push.fd.seconds(&self.fd_base()) * 1e3,
            rate(self.bitrate),
            rate(self.data_bitrate),
            if self.from_network {
                ""
            } else {
                " (no [bus] in the file)"
            },
        )
    }
}

/// `500 kbit/s`, `2 Mbit/s`.
fn rate(bits: u32) -> String {
    if bits.is_multiple_of(1_000_000) {
        format!("{} Mbit/s", bits / 1_000_000)
    } else if bits.is_multiple_of(1_000) {
        format!("{} kbit/s", bits / 1_000)
    } else {
        format!("{bits} bit/s")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(len: usize) -> Vec<u8> {
        (0..len).map(|i| (i * 7 + 3) as u8).collect()
    }

    #[test]
    fn frames_are_iso_tp_s_count() {
        let base = TimeBase::new(500_000, Some(2_000_000));
        // Classic: a first frame of 6 bytes, consecutive frames of 7, a flow control after the
        // first frame and after every 8 consecutive frames but the last block.
        for (len, frames, flow_controls) in [(7, 1, 0), (8, 2, 1), (190, 28, 4), (136, 20, 3)] {
            let push = push_frames(&image(len), 1, false, &base).unwrap();
            assert_eq!(
                (push.frames, push.flow_controls),
                (frames, flow_controls),
                "{len}"
            );
        }
        // CAN FD at TX_DL 64: a single frame up to 62 bytes, a first frame of 62, consecutive
        // frames of 63.
        for (len, frames, flow_controls) in [(62, 1, 0), (63, 2, 1), (190, 4, 1), (136, 3, 1)] {
            let push = push_frames(&image(len), 1, true, &base).unwrap();
            assert_eq!(
                (push.frames, push.flow_controls),
                (frames, flow_controls),
                "{len}"
            );
        }
        // Above 4 095 bytes the first frame's escape (a 32-bit length) on both kinds.
        let classic = push_frames(&image(4_953), 1, false, &base).unwrap();
        let fd = push_frames(&image(4_953), 1, true, &base).unwrap();
        // The HIL suite's figure push-classic-vs-fd, counted on the bus: 709 and 79 frames.
        assert_eq!((classic.frames, fd.frames), (709, 79));
        assert!(fd.units * 5 < classic.units, "{fd:?} {classic:?}");
    }

    #[test]
    fn times_are_the_frames_bits() {
        // One classic single frame of 8 bytes at 500 kbit/s: 44 + 64 + 3 bits + stuffing, µs
        // at 2 µs a bit; within the worst case.
        let base = TimeBase::new(500_000, None);
        let push = push_frames(&image(7), 1, false, &base).unwrap();
        let seconds = push.seconds(&base);
        assert!(
            (111.0 * 2e-6..=160.0 * 2e-6).contains(&seconds),
            "{seconds}"
        );
        assert!(push_frames(&image(MAX_IMAGE + 1), 1, false, &base).is_err());
        assert!(push_frames(&image(10), 0, false, &base).is_err());
    }
}
