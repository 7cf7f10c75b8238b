//! The CAN socket's receive queue in the kernel: how large it is, and how many frames the kernel
//! dropped because it was full.
//!
//! Why it matters: the kernel queues every frame of the bus for the socket until the node reads
//! it, and drops what does not fit. The node reads as fast as it arbitrates, but a process can be
//! descheduled for tens of milliseconds (a loaded computer, a table being stored), and the
//! default queue (`net.core.rmem_default`, 208 KiB: 277 frames, 13 ms of a saturated 1 Mbit/s
//! bus) overflows in that time. So the queue is sized for [`WINDOW_MS`] of a saturated bus, and
//! the kernel's drop counter (`SO_RXQ_OVFL`, sent with every frame read) is read so that what is
//! lost anyway is counted, never silent.

use std::io::{self, IoSliceMut};
use std::os::fd::{AsFd, AsRawFd, BorrowedFd};

use nix::sys::socket::{self, ControlMessageOwned, MsgFlags, sockopt};

/// The fastest classic CAN bus, in bit/s: a queue sized for it is large enough for every slower
/// one.
pub const BUS_BITRATE: u64 = 1_000_000;
/// The shortest frame on the wire, in bits: 11-bit identifier, no data, no stuff bits (44 bits),
/// plus the 3-bit intermission. A saturated bus of these is the most frames per second.
pub const SHORTEST_FRAME_BITS: u64 = 47;
/// How long the queue must hold a saturated bus while the node does not read.
pub const WINDOW_MS: u64 = 100;
/// What the kernel charges a CAN socket's receive buffer per queued frame: the frame's socket
/// buffer's `truesize`, whatever the frame's length. Measured, not derived: on Linux 6.1
/// (x86_64, Debian 12, vcan), a socket that did not read, with a 1 MiB buffer, queued exactly
/// 1 366 = ⌈1 048 576 / 768⌉ frames and counted the rest of 5 000 as dropped, from `cangen` and
/// from a Python socket alike, with the drop counter accounting for the rest (`hil-sim/run-hil
/// --command "python -m pab_hil.truesize"` measures it again). Other kernels and drivers may
/// charge somewhat differently: `--rcvbuf` adjusts.
pub const FRAME_TRUESIZE: u64 = 768;
/// The frames of [`WINDOW_MS`] of a saturated bus: ⌈1 000 000 / 47 / 10⌉ = 2 128.
pub const WINDOW_FRAMES: u64 = (BUS_BITRATE * WINDOW_MS).div_ceil(SHORTEST_FRAME_BITS * 1000);
/// The default receive buffer, in bytes as the kernel counts them (what `SO_RCVBUF` reads back):
/// 2 128 frames × 768 = 1 634 304 bytes.
pub const DEFAULT_BYTES: u64 = WINDOW_FRAMES * FRAME_TRUESIZE;
/// The smallest `--rcvbuf`: below this the kernel raises the buffer to its own minimum anyway.
pub const MIN_BYTES: u64 = 8192;
/// The largest `--rcvbuf`: the kernel stores twice the requested value in an `int`.
pub const MAX_BYTES: u64 = 1 << 30;

/// How the receive buffer was set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sizing {
    /// What was asked, in bytes as the kernel counts them.
    pub asked: u64,
    /// What the kernel reports now (`SO_RCVBUF`).
    pub got: u64,
    /// Why it is less than asked, if it is: what to do about it.
    pub shortfall: Option<String>,
}

impl Sizing {
    /// The frames the buffer holds, at [`FRAME_TRUESIZE`] each.
    pub fn frames(&self) -> u64 {
        self.got / FRAME_TRUESIZE
    }

    /// The milliseconds of a saturated [`BUS_BITRATE`] bus the buffer holds.
    pub fn window_ms(&self) -> u64 {
        self.frames() * SHORTEST_FRAME_BITS * 1000 / BUS_BITRATE
    }
}

/// Sets `socket`'s receive buffer to `bytes` (as the kernel counts them: it doubles what
/// `SO_RCVBUF` is given, for its bookkeeping, so half is asked). Beyond `net.core.rmem_max` it
/// takes `SO_RCVBUFFORCE`, which needs `CAP_NET_ADMIN` (root); without it the buffer is what
/// `rmem_max` allows, and [`Sizing::shortfall`] says how to raise it. Fails only if the socket
/// refuses the plain `SO_RCVBUF` or cannot say what it got.
pub fn set_size(socket: BorrowedFd<'_>, bytes: u64) -> io::Result<Sizing> {
    let request = usize::try_from(bytes.div_ceil(2)).unwrap_or(usize::MAX);
    let rmem_max = rmem_max();
    let mut refused = None;
    if rmem_max.is_none_or(|max| request as u64 > max)
        && let Err(error) = socket::setsockopt(&socket, sockopt::RcvBufForce, &request)
    {
        refused = Some(error);
    }
    if refused.is_some() || rmem_max.is_some_and(|max| request as u64 <= max) {
        socket::setsockopt(&socket, sockopt::RcvBuf, &request).map_err(io::Error::from)?;
    }
    let got = socket::getsockopt(&socket, sockopt::RcvBuf).map_err(io::Error::from)? as u64;
    let shortfall = (got < bytes).then(|| {
        let max = rmem_max.map_or("unknown".to_string(), |max| max.to_string());
        let why = match refused {
            Some(error) => {
                format!("SO_RCVBUFFORCE was refused ({error}: it needs root or CAP_NET_ADMIN)")
            }
            None => "the kernel gave less".to_string(),
        };
        format!(
            "the CAN socket's receive buffer is {got} bytes, not the {bytes} asked: \
             net.core.rmem_max is {max} and {why}. It holds {} frames; a saturated bus \
             overflows it in {} ms and the frames beyond are lost (counted in Errors and the \
             RxOverrun fault). Run pab-node as root, or raise the limit: \
             sysctl -w net.core.rmem_max={request}",
            got / FRAME_TRUESIZE,
            got / FRAME_TRUESIZE * SHORTEST_FRAME_BITS * 1000 / BUS_BITRATE,
        )
    });
    Ok(Sizing {
        asked: bytes,
        got,
        shortfall,
    })
}

/// `net.core.rmem_max`, if /proc says.
fn rmem_max() -> Option<u64> {
    std::fs::read_to_string("/proc/sys/net/core/rmem_max")
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// Asks the kernel to send its drop counter with every frame read (`SO_RXQ_OVFL`).
pub fn count_drops(socket: BorrowedFd<'_>) -> io::Result<()> {
    socket::setsockopt(&socket, sockopt::RxqOvfl, &1).map_err(io::Error::from)
}

/// Reads one datagram (a CAN frame) from `socket` into `buf` without blocking: its length, and
/// the kernel's drop counter as it was when the datagram was queued (`None`: the kernel sent none,
/// which it does while the counter is 0). Fails as `recvmsg` does (`WouldBlock` when the queue is
/// empty).
pub fn receive(socket: impl AsFd, buf: &mut [u8]) -> io::Result<(usize, Option<u32>)> {
    let mut space = nix::cmsg_space!(u32);
    let mut iov = [IoSliceMut::new(buf)];
    let message = socket::recvmsg::<()>(
        socket.as_fd().as_raw_fd(),
        &mut iov,
        Some(&mut space),
        MsgFlags::MSG_DONTWAIT,
    )
    .map_err(io::Error::from)?;
    let mut counter = None;
    for control in message.cmsgs().map_err(io::Error::from)? {
        if let ControlMessageOwned::RxqOvfl(dropped) = control {
            counter = Some(dropped);
        }
    }
    Ok((message.bytes, counter))
}

/// The kernel's drop counter, turned into "frames lost since the last frame read".
///
/// The kernel's counter (`sk_drops`) counts every frame dropped since the socket was opened and
/// wraps at 2³²; each frame read carries its value at the time the frame was queued. So the
/// frames lost between two frames read are the difference of their counters, modulo 2³². Frames
/// dropped after the last frame read are counted when the next one arrives (on a live bus, within
/// a heartbeat period of another node).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct DropCount {
    seen: u32,
}

impl DropCount {
    /// The frames lost since the previous call, given the counter that came with a frame
    /// (`None`: the kernel sent none, so its counter is still 0).
    pub fn lost_since_last(&mut self, counter: Option<u32>) -> u32 {
        let counter = counter.unwrap_or(0);
        let lost = counter.wrapping_sub(self.seen);
        self.seen = counter;
        lost
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::UdpSocket;

    #[test]
    fn the_default_buffer_holds_100_ms_of_a_saturated_1_mbit_bus() {
        assert_eq!(WINDOW_FRAMES, 2128);
        assert_eq!(DEFAULT_BYTES, 1_634_304);
        let sizing = Sizing {
            asked: DEFAULT_BYTES,
            got: DEFAULT_BYTES,
            shortfall: None,
        };
        assert_eq!(sizing.frames(), 2128);
        assert!(sizing.window_ms() >= WINDOW_MS, "{}", sizing.window_ms());
        // One frame fewer would not do.
        let short = Sizing {
            got: DEFAULT_BYTES - FRAME_TRUESIZE,
            ..sizing
        };
        assert!(short.window_ms() < WINDOW_MS);
    }

    #[test]
    fn losses_are_counter_differences_modulo_2_to_the_32() {
        let mut count = DropCount::default();
        assert_eq!(count.lost_since_last(None), 0);
        assert_eq!(count.lost_since_last(Some(5)), 5);
        assert_eq!(count.lost_since_last(Some(5)), 0);
        assert_eq!(count.lost_since_last(Some(u32::MAX)), u32::MAX - 5);
        // The kernel's counter wrapped: 3 more lost.
        assert_eq!(count.lost_since_last(Some(2)), 3);
    }

    /// The kernel's drop counter, through the real `recvmsg` path, on a UDP socket over loopback
    /// (this machine's kernel has no SocketCAN; `SO_RXQ_OVFL` is the same socket-level option
    /// for both): a socket with a small buffer that does not read while 2 000 datagrams arrive
    /// counts exactly those it dropped.
    #[test]
    fn the_kernel_drop_counter_accounts_for_every_datagram_not_queued() {
        let receiver = UdpSocket::bind("127.0.0.1:0").unwrap();
        let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
        sender.connect(receiver.local_addr().unwrap()).unwrap();
        count_drops(receiver.as_fd()).unwrap();
        let sizing = set_size(receiver.as_fd(), MIN_BYTES).unwrap();
        assert!(sizing.got >= MIN_BYTES, "{sizing:?}");
        const SENT: u32 = 2000;
        for i in 0..SENT {
            sender.send(&i.to_le_bytes()).unwrap();
        }
        let mut count = DropCount::default();
        let (mut read, mut lost) = (0u32, 0u32);
        let mut expected_next = 0u32;
        let mut buf = [0u8; 16];
        loop {
            match receive(&receiver, &mut buf) {
                Ok((len, counter)) => {
                    assert_eq!(len, 4);
                    let index = u32::from_le_bytes(buf[..4].try_into().unwrap());
                    let newly = count.lost_since_last(counter);
                    // What was lost sits exactly between the previous datagram read and this one.
                    assert_eq!(index - expected_next, newly, "datagram {index}");
                    expected_next = index + 1;
                    read += 1;
                    lost += newly;
                }
                Err(error) if error.kind() == io::ErrorKind::WouldBlock => break,
                Err(error) => panic!("{error}"),
            }
        }
        // The drops after the last datagram read are reported with the next one.
        sender.send(&SENT.to_le_bytes()).unwrap();
        let (_, counter) = receive(&receiver, &mut buf).unwrap();
        lost += count.lost_since_last(counter);
        assert!(lost > 0, "the buffer should have overflowed ({read} read)");
        assert_eq!(read + lost, SENT, "read {read}, lost {lost}");
    }

    #[test]
    fn a_buffer_beyond_rmem_max_is_forced_as_root_or_explained() {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        let max = rmem_max().expect("/proc/sys/net/core/rmem_max");
        let asked = (max * 2 + 65536).min(MAX_BYTES);
        let sizing = set_size(socket.as_fd(), asked).unwrap();
        if is_root() {
            assert!(sizing.got >= asked, "{sizing:?}");
            assert_eq!(sizing.shortfall, None);
        } else {
            assert!(sizing.got < asked, "{sizing:?}");
            let text = sizing.shortfall.expect("a shortfall explained");
            assert!(text.contains("net.core.rmem_max"), "{text}");
            assert!(text.contains("SO_RCVBUFFORCE"), "{text}");
        }
    }

    /// The effective user id, from /proc (no `unsafe` for `geteuid`).
    fn is_root() -> bool {
        std::fs::read_to_string("/proc/self/status")
            .unwrap()
            .lines()
            .find_map(|line| line.strip_prefix("Uid:"))
            .and_then(|ids| ids.split_whitespace().nth(1).map(|euid| euid == "0"))
            .unwrap()
    }
}
