//! A node on a thread, in real time, on the in-process bus: the board application (`pab-app`,
//! full capacities, every feature the workspace builds it with) as `pab_app::run` runs it, with
//! std time. Shared by the live-bus tests. With [`Update`], the node has an identity and an
//! update slot over in-memory flash, and takes firmware updates (`pabctl flash`).
#![allow(dead_code)]

pub mod schema_rig;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use pab_app::{Config, FullNode, SaveProgress, Step, StoreError, TableStore};
use pab_storage::testing::MemFlash;
use pab_storage::{UpdateSlot, WithUpdate};
use pabctl::bus::Bus;
use pabctl::bus::memory::{MemoryBus, MemoryHub};

/// A node thread and what it stored.
pub struct LiveNode {
    stop: Arc<AtomicBool>,
    pub stored: Arc<Mutex<Vec<Vec<u8>>>>,
    /// Set when the node committed a firmware update and restarted into its bootloader (what
    /// the runner does through `Watchdog::restart`): its thread has ended, as a board resets.
    pub restarted: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// The update slot's length: 16 KiB, eight pages of 2 KiB (the G474's erase page).
pub const SLOT_LEN: u32 = 16 * 1024;
/// The update (DFU) partition of a [`LiveNode`] with [`Update`].
pub type DfuFlash = MemFlash<8, 2048, 8>;
/// Its request page.
pub type RequestFlash = MemFlash<1, 2048, 8>;

/// A flash that the node thread and the test share: the test reads what the node wrote, and
/// writes what a bootloader would, between two nodes.
pub struct Shared<F>(pub Arc<Mutex<F>>);

impl<F> Clone for Shared<F> {
    fn clone(&self) -> Self {
        Shared(self.0.clone())
    }
}

impl<F: Default> Shared<F> {
    /// An erased flash.
    pub fn erased() -> Self {
        Shared(Arc::new(Mutex::new(F::default())))
    }
}

impl<const P: usize, const E: usize, const W: usize> Shared<MemFlash<P, E, W>> {
    /// Every byte of the flash.
    pub fn bytes(&self) -> Vec<u8> {
        self.0.lock().unwrap().pages().concat()
    }
}

impl<F: ErrorType> ErrorType for Shared<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Shared<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.lock().unwrap().read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.lock().unwrap().capacity()
    }
}

impl<F: NorFlash> NorFlash for Shared<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.lock().unwrap().erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.lock().unwrap().write(offset, bytes)
    }
}

/// What makes a [`LiveNode`] updatable: the firmware it says it runs (its identity), and its
/// update partition and request page.
#[derive(Clone)]
pub struct Update {
    pub firmware: pab_app::Firmware,
    pub dfu: Shared<DfuFlash>,
    pub request: Shared<RequestFlash>,
}

/// A table store that keeps no table (the live nodes' tables go to [`LiveNode::stored`]): the
/// table half of the updatable node's `WithUpdate`.
struct NoTables;

impl TableStore for NoTables {
    fn load<'b>(&mut self, _: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        Ok(None)
    }

    fn start_save(&mut self, _: &[u8]) -> Result<(), StoreError> {
        Ok(())
    }

    fn continue_save(&mut self, _: &[u8]) -> Result<SaveProgress, StoreError> {
        Ok(SaveProgress::Done)
    }
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
        Self::spawn_updatable(hub, id, boot_image, key, None)
    }

    /// [`LiveNode::spawn_with`], the node with an identity and an update slot when `update` is
    /// given: at start it reports the verdict the request page holds (as `pab_app::run_watched`
    /// does), and it takes firmware updates.
    pub fn spawn_updatable(
        hub: &MemoryHub,
        id: u8,
        boot_image: Option<Vec<u8>>,
        key: Option<pab_core::auth::Key>,
        update: Option<Update>,
    ) -> LiveNode {
        let stop = Arc::new(AtomicBool::new(false));
        let stored = Arc::new(Mutex::new(Vec::new()));
        let restarted = Arc::new(AtomicBool::new(false));
        let mut bus = hub.connect();
        let (stop_flag, store, restart) = (stop.clone(), stored.clone(), restarted.clone());
        let thread = std::thread::spawn(move || {
            let options = Options {
                id,
                boot_image,
                key,
                update,
            };
            run_node(&mut bus, options, &stop_flag, &store, &restart);
        });
        LiveNode {
            stop,
            stored,
            restarted,
            thread: Some(thread),
        }
    }

    /// Waits up to `timeout` for the node to restart into its bootloader; whether it did.
    pub fn wait_restart(&self, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if self.restarted.load(Ordering::SeqCst) {
                return true;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        false
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

struct Options {
    id: u8,
    boot_image: Option<Vec<u8>>,
    key: Option<pab_core::auth::Key>,
    update: Option<Update>,
}

/// What `pab_app::run` does, with std time and the in-process bus.
fn run_node(
    bus: &mut MemoryBus,
    options: Options,
    stop: &AtomicBool,
    stored: &Mutex<Vec<Vec<u8>>>,
    restarted: &AtomicBool,
) {
    let Options {
        id,
        boot_image,
        key,
        update,
    } = options;
    let start = Instant::now();
    let now = || pab_core::Instant::from_micros(start.elapsed().as_micros() as u64);
    let mut node = Box::new(FullNode::new(Config::new(id).unwrap(), now()));
    if let Some(key) = key {
        node.set_key(&key, 1);
    }
    let mut slot = update.map(|update| {
        node.set_identity(update.firmware, [id; pab_core::identity::UID_LEN]);
        let slot = UpdateSlot::new(update.dfu, update.request, SLOT_LEN).unwrap();
        WithUpdate::new(NoTables, slot, || true)
    });
    let len = boot_image.map(|image| {
        node.boot_buffer()[..image.len()].copy_from_slice(&image);
        image.len()
    });
    node.boot(len, now());
    // As `pab_app::run_watched` at start: the slot to the node, the bootloader's verdict.
    if let Some(slot) = slot.as_mut() {
        node.set_update_slot(slot.update_slot_len());
        if let Some(verdict) = slot.take_update_verdict().unwrap() {
            node.update_verdict(verdict);
        }
    }
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
        // As the runner's `write_update` and `request_update`.
        if let Some(slot) = slot.as_mut() {
            if step == Step::WriteUpdate {
                let ok = match node.update_chunk() {
                    Some((offset, data)) => slot.write_update(offset, data).is_ok(),
                    None => false,
                };
                node.update_written(ok);
            }
            if step == Step::RequestUpdate {
                let ok = match node.update_manifest() {
                    Some(manifest) => slot.request_update(manifest).is_ok(),
                    None => false,
                };
                if node.update_requested(ok) {
                    // The answer out, then the restart (`Watchdog::restart` on a board): the
                    // thread ends, as the board's firmware does.
                    while let Some(frame) = node.next_outgoing() {
                        bus.send(&frame).unwrap();
                    }
                    restarted.store(true, Ordering::SeqCst);
                    return;
                }
            }
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
