//! Who the node is, and the configuration it takes over the bus: its identity answers, the
//! assignment of its node id, its bit rate and the trial of a new one (docs/can-protocol.md,
//! "Identity and configuration").
//!
//! Nothing here is on the frame path: an unassigned node never arbitrates, an identity request
//! or a command is a protocol frame, and the bit rate's trial ends in [`Node::poll`] at its
//! deadline. The trial needs no per-frame work either: the node heard the bus if its received
//! count moved since the trial began.

use pab_core::identity::{self, Capacity, Firmware, Identity, IdentityPart, UID_LEN};
use pab_core::protocol::{Assign, ConfigStatus, ConfigStatusCode, Configure};

use super::*;
use crate::settings::{BITRATE_TRIAL_US, Settings, bitrate_code};

/// The shortest time between two identity answers, µs: a flood of requests costs the bus at
/// most six frames per 20 ms (a tool that asks twice at once gets one answer, which serves both).
const IDENTITY_INTERVAL_US: u64 = 20_000;

/// What the node knows of itself ([`Node::set_identity`], [`Node::set_settings`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct Me {
    uid: [u8; UID_LEN],
    pub(super) firmware: Firmware,
    /// The bit rate it runs at, kbit/s (0: its host's, as on a Linux socket).
    bitrate_kbps: u16,
    /// What its configuration page holds (or will, once a pending save is done).
    settings: Settings,
    /// No node id: it sends from its provisional address and takes only identity requests and
    /// assignments.
    pub(super) unassigned: bool,
    /// The trial of a bit rate set over the bus: when it ends, and the frames received before it.
    trial: Option<(Instant, u32)>,
    /// A configuration record for the runner to store ([`Step::SaveSettings`]).
    pending: Option<Pending>,
    /// No identity answer before then.
    next_answer: Instant,
}

/// A configuration record waiting for its save, and what follows it.
#[derive(Clone, Copy, Debug)]
struct Pending {
    settings: Settings,
    /// The command it answers, and to whom.
    answer: Option<(Service, u8)>,
    /// The node's new id, in force once stored.
    node_id: Option<u8>,
    /// The runner restarts the node once it is stored (a failed trial).
    restart: bool,
}

impl Me {
    pub(super) fn new(unassigned: bool, now: Instant) -> Me {
        // A constant: `Firmware::new`'s loops evaluated at compile time, not at start.
        const UNKNOWN: Firmware = Firmware::new("pab", "0.0.0", "");
        Me {
            uid: [0; UID_LEN],
            firmware: UNKNOWN,
            bitrate_kbps: 0,
            settings: Settings::default(),
            unassigned,
            trial: None,
            pending: None,
            next_answer: now,
        }
    }

    /// When the trial ends, if one runs.
    pub(super) fn deadline(&self) -> Option<Instant> {
        self.trial.map(|(until, _)| until)
    }
}

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// Says who the node is: its firmware and its unique id (the STM32's factory UID, the id
    /// `pab-node` keeps in its store). An unassigned node ([`crate::Config::unassigned`]) takes
    /// its provisional address from the uid. Call it before [`Node::boot`], which announces the
    /// identity.
    pub fn set_identity(&mut self, firmware: Firmware, uid: [u8; UID_LEN]) {
        self.me.firmware = firmware;
        self.me.uid = uid;
        if self.me.unassigned {
            self.config.node_id = identity::provisional_address(&uid);
        }
    }

    /// Gives the node what its configuration page held at start (`loaded`, as
    /// [`pab_storage::TableStore::load_settings`] returned it: read with
    /// [`Settings::from_loaded`] before the node was made, for its node id) and the bit rate it
    /// runs at (`bitrate_kbps`; 0 when that is not the node's to set, as on a Linux socket).
    /// A page that could not be read, or holds a record of another format, raises
    /// [`FaultCode::SettingsUnreadable`] (the defaults apply). A bit rate on trial starts its
    /// 5 s at `now`: the node must hear a frame by then, or it stores its previous rate again and
    /// asks the runner to restart ([`Node::settings_stored`]). A last trial that fell back raises
    /// [`FaultCode::BitrateFallback`].
    pub fn set_settings(
        &mut self,
        loaded: Result<Option<u16>, StoreError>,
        bitrate_kbps: u16,
        now: Instant,
    ) {
        let settings = Settings::from_loaded(&loaded);
        let unreadable = match loaded {
            Ok(Some(record)) if Settings::from_record(record).is_none() => Some(5),
            Ok(_) => None,
            Err(StoreError::Flash(_)) => Some(1),
            Err(StoreError::Layout(_)) => Some(2),
            Err(StoreError::SequenceExhausted) => Some(3),
            Err(_) => Some(4),
        };
        if let Some(reason) = unreadable {
            warn!(
                "configuration page unreadable ({}): compiled defaults",
                int(u32::from(reason))
            );
            self.raise(FaultCode::SettingsUnreadable, [reason, 0, 0, 0, 0]);
        }
        self.me.settings = settings;
        self.me.bitrate_kbps = bitrate_kbps;
        if settings.trial && bitrate_kbps != 0 {
            self.me.trial = Some((
                now.wrapping_add_micros(BITRATE_TRIAL_US),
                self.counters.received,
            ));
        }
        if settings.fell_back {
            let [f0, f1] = settings.previous_kbps.unwrap_or(0).to_le_bytes();
            let [b0, b1] = bitrate_kbps.to_le_bytes();
            self.raise(FaultCode::BitrateFallback, [f0, f1, b0, b1, 0]);
        }
    }

    /// The node's identity as it answers it.
    pub fn identity(&self) -> Identity {
        let keyed = if self.guard.locked().is_some() {
            Identity::FLAG_LOCKED
        } else if self.guard.is_keyed() {
            Identity::FLAG_KEYED
        } else {
            0
        };
        let flags = keyed
            | if self.me.unassigned {
                Identity::FLAG_UNASSIGNED
            } else {
                0
            }
            | if self.me.trial.is_some() {
                Identity::FLAG_BITRATE_TRIAL
            } else {
                0
            }
            | if self.me.settings.fell_back {
                Identity::FLAG_BITRATE_FELL_BACK
            } else {
                0
            };
        let features = if cfg!(feature = "ble") {
            Identity::FEATURE_BLE
        } else {
            0
        } | if cfg!(feature = "filters") {
            Identity::FEATURE_FILTERS
        } else {
            0
        } | if cfg!(feature = "dynamics") {
            Identity::FEATURE_DYNAMICS
        } else {
            0
        } | if cfg!(feature = "schema") {
            Identity::FEATURE_SCHEMA
        } else {
            0
        } | if cfg!(feature = "fd") {
            Identity::FEATURE_FD
        } else {
            0
        };
        let format = u8::try_from(image::FORMAT_VERSION).unwrap_or(u8::MAX);
        let clamp = |n: usize| u16::try_from(n).unwrap_or(u16::MAX);
        Identity {
            uid: self.me.uid,
            firmware: self.me.firmware,
            protocol: identity::PROTOCOL_VERSION,
            formats: [format, format],
            capacity: Capacity {
                ports: u8::try_from(P).unwrap_or(u8::MAX),
                connections: clamp(C),
                decision_nodes: clamp(N),
                image_len: clamp(IMG),
            },
            features,
            flags,
            bitrate_kbps: self.me.bitrate_kbps,
        }
    }

    /// Queues the six identity frames to `destination`. Out of line: two callers (the answer,
    /// the announcement at start).
    #[inline(never)]
    pub(super) fn send_identity(&mut self, destination: u8) {
        let identity = self.identity();
        for part in IdentityPart::ALL {
            self.send(
                Message::Identity {
                    part,
                    payload: identity.payload(part),
                },
                destination,
            );
        }
    }

    /// An identity request from `source`: answered, at most once per 20 ms.
    pub(super) fn on_identity_request(&mut self, source: u8, now: Instant) {
        if now.micros_since(self.me.next_answer).is_none() {
            return;
        }
        self.me.next_answer = now.wrapping_add_micros(IDENTITY_INTERVAL_US);
        self.send_identity(source);
    }

    /// Whether a keyed node takes this command (`payload`, its `tag`), else the refusal raised.
    fn command_allowed(
        &mut self,
        id: FrameId,
        payload: [u8; 4],
        tag: Option<[u8; 4]>,
        now: Instant,
    ) -> bool {
        let verdict = match tag {
            None => self.guard.plain_allowed(),
            Some(tag) => {
                self.guard
                    .command(self.config.node_id, id.service.code(), &payload, &tag, now)
            }
        };
        match verdict {
            Ok(()) => true,
            Err(failure) => {
                self.unauthenticated(failure, id);
                false
            }
        }
    }

    /// An Assign to this node's address: ignored unless its uid check is this node's; then
    /// refused (an unauthenticated one, a save in progress) or handed to the runner to store.
    pub(super) fn on_assign(&mut self, id: FrameId, assign: &Assign, now: Instant) -> Step {
        if assign.uid_check != identity::uid_check(&self.me.uid) {
            return Step::Continue;
        }
        if !self.command_allowed(id, assign.payload(), assign.tag, now) {
            return Step::Continue;
        }
        let settings = Settings {
            node_id: Some(assign.node_id),
            ..self.me.settings
        };
        self.save_settings(settings, id, Some(assign.node_id))
    }

    /// A Configure to this node: the bit rate from the next start, stored (the running one
    /// becomes the trial's fallback).
    pub(super) fn on_configure(
        &mut self,
        id: FrameId,
        configure: &Configure,
        now: Instant,
    ) -> Step {
        if !self.command_allowed(id, configure.payload(), configure.tag, now) {
            return Step::Continue;
        }
        // A host-set rate (0: a Linux socket's), or a rate the board cannot run.
        let refusal = if self.me.bitrate_kbps == 0 {
            Some(ConfigStatusCode::Unsupported)
        } else if bitrate_code(configure.bitrate_kbps).is_none() {
            Some(ConfigStatusCode::BadValue)
        } else {
            None
        };
        if let Some(status) = refusal {
            self.config_answer(id.service, id.source, status);
            return Step::Continue;
        }
        let settings = Settings {
            bitrate_kbps: Some(configure.bitrate_kbps),
            previous_kbps: Some(self.me.bitrate_kbps),
            trial: true,
            fell_back: false,
            ..self.me.settings
        };
        self.save_settings(settings, id, None)
    }

    fn save_settings(&mut self, settings: Settings, id: FrameId, node_id: Option<u8>) -> Step {
        // One flash operation at a time: not while a table's save waits or runs.
        if self.me.pending.is_some() || self.awaiting_store.is_some() || self.store_due.is_some() {
            self.config_answer(id.service, id.source, ConfigStatusCode::Busy);
            return Step::Continue;
        }
        self.me.pending = Some(Pending {
            settings,
            answer: Some((id.service, id.source)),
            node_id,
            restart: false,
        });
        Step::SaveSettings
    }

    /// The bit rate's trial, at its deadline: the bus was heard (committed: the trial flag
    /// cleared), or not (the previous rate stored again, to restart on).
    pub(super) fn trial_due(&mut self, now: Instant) -> Step {
        let Some((until, received)) = self.me.trial else {
            return Step::Continue;
        };
        if now.micros_since(until).is_none() || self.me.pending.is_some() {
            return Step::Continue;
        }
        self.me.trial = None;
        let settings = &self.me.settings;
        let heard = self.counters.received != received;
        let settings = if heard {
            Settings {
                trial: false,
                ..*settings
            }
        } else {
            warn!(
                "bit rate {} kbit/s heard nothing for 5 s: back to the previous rate",
                int(u32::from(self.me.bitrate_kbps))
            );
            Settings {
                bitrate_kbps: settings.previous_kbps,
                previous_kbps: Some(self.me.bitrate_kbps),
                trial: false,
                fell_back: true,
                ..*settings
            }
        };
        self.me.pending = Some(Pending {
            settings,
            answer: None,
            node_id: None,
            restart: !heard,
        });
        Step::SaveSettings
    }

    /// The configuration record to store after [`Step::SaveSettings`]
    /// ([`pab_storage::TableStore::save_settings`]), then call [`Node::settings_stored`].
    pub fn settings_to_store(&self) -> u16 {
        self.me
            .pending
            .map_or(self.me.settings, |pending| pending.settings)
            .record()
    }

    /// Reports the outcome of storing [`Node::settings_to_store`] (`Ok(true)` stored, `Ok(false)`
    /// nowhere to store it, in force until exit): a new node id is in force from now (the table
    /// that ran, made for the old id, stops), the command is answered. `true`: restart now (a
    /// bit rate's trial failed and the previous rate is stored).
    pub fn settings_stored(&mut self, result: Result<bool, StoreError>, now: Instant) -> bool {
        let Some(pending) = self.me.pending.take() else {
            return false;
        };
        let status = match result {
            Ok(true) => ConfigStatusCode::Stored,
            Ok(false) => ConfigStatusCode::NotStored,
            Err(_) => ConfigStatusCode::StoreFailed,
        };
        if status != ConfigStatusCode::StoreFailed {
            self.me.settings = pending.settings;
            if let Some(node_id) = pending.node_id
                && node_id != self.config.node_id
            {
                self.take_node_id(node_id, now);
            }
        }
        if let Some((command, requester)) = pending.answer {
            self.config_answer(command, requester, status);
        }
        // No `duties` here: the answer is in the outbox, which the runner sends at its next
        // turn (a copy of the duties inlined here took some 600 bytes of the boards' flash).
        pending.restart
    }

    /// Becomes node `node_id`: announces itself under it. A table that ran was made for the old
    /// id: it stops (the store keeps it; at the next start it is refused as WrongNode).
    fn take_node_id(&mut self, node_id: u8, now: Instant) {
        info!("node id {}", int(u32::from(node_id)));
        self.config.node_id = node_id;
        self.me.unassigned = false;
        self.arbiter = None;
        self.running = None;
        self.incoming = None;
        // The table's schema server goes with it (not `start_schema`: a second caller took it
        // out of line, 280 bytes of the NUCLEO-G474RE's flash).
        #[cfg(feature = "schema")]
        {
            self.schema = None;
            self.schema_on = false;
        }
        self.next_heartbeat = now;
        self.send_identity(protocol::BROADCAST);
    }

    fn config_answer(&mut self, command: Service, requester: u8, status: ConfigStatusCode) {
        let settings = self
            .me
            .pending
            .map_or(self.me.settings, |pending| pending.settings);
        let node_id = if self.me.unassigned {
            0
        } else {
            self.config.node_id
        };
        self.send(
            Message::ConfigStatus(ConfigStatus {
                command: command.code(),
                status,
                node_id,
                bitrate_kbps: settings.bitrate_kbps.unwrap_or(self.me.bitrate_kbps),
            }),
            requester,
        );
    }
}
