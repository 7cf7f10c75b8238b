//! A node on a thread, in real time, on the in-process bus: the board application (`pab-app`,
//! full capacities, every feature the workspace builds it with) as `pab_app::run` runs it, with
//! std time. Shared by the live-bus tests.
#![allow(dead_code)]

pub mod schema_rig;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use pab_app::{Config, FullNode, Step};
use pabctl::bus::Bus;
use pabctl::bus::memory::{MemoryBus, MemoryHub};

/// A node thread and what it stored.
pub struct LiveNode {
    stop: Arc<AtomicBool>,
    pub stored: Arc<Mutex<Vec<Vec<u8>>>>,
    thread: Option<JoinHandle<()>>,
}

impl LiveNode {
    pub fn spawn(hub: &MemoryHub, id: u8, boot_image: Option<Vec<u8>>) -> LiveNode {
        Self::spawn_with(hub, id, boot_image, None)
    }

    /// [`LiveNode::spawn`], the node with `key` (boot salt 1) when given.
    pub fn spawn_with(
        hub: &MemoryHub,
        id: u8,
        boot_image: Option<Vec<u8>>,
        key: Option<pab_core::auth::Key>,
    ) -> LiveNode {
        let stop = Arc::new(AtomicBool::new(false));
        let stored = Arc::new(Mutex::new(Vec::new()));
        let mut bus = hub.connect();
        let (stop_flag, store) = (stop.clone(), stored.clone());
        let thread = std::thread::spawn(move || {
            run_node(&mut bus, id, boot_image, key, &stop_flag, &store);
        });
        LiveNode {
            stop,
            stored,
            thread: Some(thread),
        }
    }
}

impl Drop for LiveNode {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// What `pab_app::run` does, with std time and the in-process bus.
fn run_node(
    bus: &mut MemoryBus,
    id: u8,
    boot_image: Option<Vec<u8>>,
    key: Option<pab_core::auth::Key>,
    stop: &AtomicBool,
    stored: &Mutex<Vec<Vec<u8>>>,
) {
    let start = Instant::now();
    let now = || pab_core::Instant::from_micros(start.elapsed().as_micros() as u64);
    let mut node = Box::new(FullNode::new(Config::new(id).unwrap(), now()));
    if let Some(key) = key {
        node.set_key(&key, 1);
    }
    let len = boot_image.map(|image| {
        node.boot_buffer()[..image.len()].copy_from_slice(&image);
        image.len()
    });
    node.boot(len, now());
    while !stop.load(Ordering::SeqCst) {
        while let Some(frame) = node.next_outgoing() {
            bus.send(&frame).unwrap();
        }
        let wait = node
            .deadline(now())
            .micros_since(now())
            .unwrap_or(0)
            .min(5_000);
        let step = match bus.receive(Duration::from_micros(wait)) {
            Ok(Some(frame)) => node.on_frame(&frame, now(), &mut ()),
            Ok(None) => node.poll(now(), &mut ()),
            Err(_) => return,
        };
        if step == Step::Store {
            stored.lock().unwrap().push(node.image_to_store().to_vec());
            node.stored(true, now());
        }
    }
}

/// A participant flooding node `node` with bad tags on its own thread until dropped: ten
/// DiagnosticControl frames a millisecond tagged with zeros, from source 9, and a challenge
/// request every thousand of them (so that some are checked against a challenge). The node's
/// checks for each second are used up; it raises Unauthenticated faults saying so.
pub struct TagFlood {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl TagFlood {
    pub fn start(hub: &MemoryHub, node: u8) -> TagFlood {
        use pab_core::protocol::{DiagnosticControl, Message};
        let stop = Arc::new(AtomicBool::new(false));
        let mut rogue = hub.connect();
        let flooding = stop.clone();
        let thread = std::thread::spawn(move || {
            let bad = Message::AuthenticatedDiagnosticControl {
                control: DiagnosticControl {
                    rate_hz: 0,
                    ports: 0,
                },
                tag: [0; 4],
            };
            let request = Message::ChallengeRequest { tool_nonce: 0 };
            let mut sent = 0u32;
            while !flooding.load(Ordering::SeqCst) {
                if sent.is_multiple_of(1000) {
                    rogue.send(&request.to_frame(9, node)).unwrap();
                }
                for _ in 0..10 {
                    rogue.send(&bad.to_frame(9, node)).unwrap();
                    sent += 1;
                }
                while let Ok(Some(_)) = rogue.receive(Duration::ZERO) {}
                std::thread::sleep(Duration::from_millis(1));
            }
        });
        TagFlood {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for TagFlood {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
