//! The enumerations carried in our frames. Codes are part of the wire format: never renumber one.

/// Defines a `#[repr(u8/u16)]` enum with `code()`, `from_code()`, `ALL` and a description, so the
/// wire value, the documentation and the DBC value tables come from one list.
macro_rules! wire_enum {
    (
        $(#[$meta:meta])*
        $name:ident: $repr:ty {
            $( $(#[$vmeta:meta])* $variant:ident = $code:expr, $text:expr; )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[repr($repr)]
        pub enum $name {
            $( $(#[$vmeta])* $variant = $code, )*
        }

        impl $name {
            /// Every value, in code order.
            pub const ALL: &'static [$name] = &[$($name::$variant),*];

            /// The wire code.
            pub const fn code(self) -> $repr {
                self as $repr
            }

            /// The value with this wire code.
            pub fn from_code(code: $repr) -> Option<$name> {
                $name::ALL.iter().copied().find(|value| value.code() == code)
            }

            /// A one-line description, as in `docs/can-protocol.md`.
            pub const fn description(self) -> &'static str {
                match self {
                    $( $name::$variant => $text, )*
                }
            }
        }

        impl core::fmt::Display for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str(self.description())
            }
        }
    };
}

wire_enum! {
    /// A node's state, in its heartbeat.
    NodeState: u8 {
        /// Booted without a valid table: it arbitrates nothing and delivers nothing.
        NoTable = 0, "no table";
        /// Arbitrating with a valid table.
        Operational = 1, "operational";
        /// Arbitrating, but something needs attention: the table could not be stored (it will be
        /// lost at reboot) or the controller is error-passive or bus-off.
        Fault = 2, "fault";
    }
}

wire_enum! {
    /// What a fault frame reports.
    FaultCode: u16 {
        /// The table found in storage at boot was refused (by the same checks as a pushed one:
        /// header, node id, CRC, loader), or the store could not be read; the node has no table.
        /// Detail byte 0: the [`TransferStatusCode`] of the verdict (byte 1: its detail, for
        /// `WrongNode` the image's node id), or [`STORE_UNREADABLE`] (byte 1: the
        /// [`StoreFailure`]). Repeated after every heartbeat group while the node has no table.
        BadStoredTable = 0x0001, "stored table refused at boot";
        /// A pushed table was refused. Detail byte 0: the [`TransferStatusCode`].
        TableRefused = 0x0002, "pushed table refused";
        /// A table was applied but could not be stored: the node will boot with the old one.
        StoreFailed = 0x0003, "table could not be stored";
        /// The controller reported a bus error. Detail byte 0: driver-specific kind.
        BusError = 0x0010, "bus error";
        /// Received frames were lost before the node read them.
        RxOverrun = 0x0011, "receive overrun";
        /// Frames to send were dropped because the transmit queue was full.
        TxOverrun = 0x0012, "transmit overrun";
        /// The controller is bus-off or error-passive.
        BusOff = 0x0013, "bus-off or error-passive";
        /// A frame of our protocol addressed to this node was malformed. Detail byte 0: its service.
        BadCommand = 0x0020, "malformed command";
        /// A configuration message or, on a keyed node, a coordination frame was refused by the
        /// authentication rules (the running table and settings are unchanged). Detail byte 0:
        /// the [`AuthFailure`]; byte 1: the service code of the refused frame (0x80: a BLE
        /// claim); byte 2: its source.
        Unauthenticated = 0x0030, "configuration refused: not authenticated";
        /// The board's key page holds something that is neither erased nor a valid key record:
        /// the node fails closed and accepts no configuration. Detail byte 0: why (1 truncated,
        /// 2 bad magic, 3 unsupported format, 4 reserved byte set, 5 CRC). Repeated after every
        /// heartbeat group.
        KeyPageInvalid = 0x0031, "key page invalid: configuration locked";
        /// A BLE claim ([`crate::ble`]) was refused: malformed, or from a sender using this
        /// node's id, or from one more peer than the group has room for. Detail byte 0: why
        /// (1 malformed, 2 this node's id, 3 no room); byte 1: the claim's node id (0 when
        /// malformed); byte 2: its group.
        ClaimRefused = 0x0040, "BLE claim refused";
        /// A competitive-dynamics group whose gates this node reads ([`crate::dynamics`]) was not
        /// heard for [`super::Gates::SILENCE_US`]: its gates read closed until it is heard again.
        /// Detail byte 0: the node that runs it; byte 1: the group.
        GatesLost = 0x0050, "dynamics gates lost";
        /// Gates of a group this node reads, with another number of behaviours than its table
        /// says (two networks on one bus, or a table not pushed yet): ignored. Detail byte 0:
        /// the sender; byte 1: the group; byte 2: the count in the frame.
        GatesRefused = 0x0051, "dynamics gates refused";
        /// A group this node runs fell more than [`crate::dynamics::MAX_CATCH_UP`] steps behind
        /// (the node stalled) and dropped the backlog. Detail bytes 0-3: the steps dropped since
        /// the table started, u32 LE, saturating; byte 4: the group's position in the table.
        DynamicsLate = 0x0052, "dynamics steps dropped";
        /// A filter command ([`super::FilterProfile`], [`super::FilterSet`]) this node cannot
        /// apply: nothing changed. Detail byte 0: why (1 no such profile, 2 not a filtered
        /// connection, 3 the running table has no message filters); byte 1: the profile, or the
        /// port; byte 2: the connection; bytes 3-4: the command's sequence number, u16 LE.
        FilterRefused = 0x0060, "filter command refused";
        /// A safety event stopped the schema server ([`crate::protocol::Service::EmergencyStop`],
        /// a stale sensor, a limit, the watchdog, an overrun): the attractor is on the measured
        /// pose and the server waits on the high-priority channel. Detail byte 0: the
        /// [`SchemaSafety`]; bytes 1-2: the schema it ended, u16 LE.
        SchemaSafety = 0x0070, "schema server stopped by a safety event";
        /// The bit rate set over the bus heard nothing (no frame received, no transmission
        /// acknowledged) within 5 s of the start: the node stored its previous rate again and
        /// restarted on it. Detail bytes 0-1: the rate that failed, kbit/s, u16 LE; bytes 2-3:
        /// the rate it went back to.
        BitrateFallback = 0x0080, "bit rate fell back";
        /// The node's configuration page could not be read at start (a flash error, or a record
        /// of another format): it runs on its compiled defaults. Detail byte 0: why (1 flash
        /// error, 2 layout, 3 records exhausted, 4 a record does not read back, 5 a record of
        /// another format).
        SettingsUnreadable = 0x0081, "configuration page unreadable";
        /// A firmware update failed: an image refused (after an update's Begin whose trailer
        /// the node refuses, or at start when the bootloader refused the image it was asked to
        /// swap in), or the update partition could not be written (the session ended). The
        /// running firmware is untouched either way. Detail byte 0: the refusal's code
        /// (`update::UpdateRefusal::code`: 1 truncated, 2 bad trailer, 3 too large, 4 another
        /// board, 5 downgrade, 6 bad signature, 7 unreadable), or 8: the partition could not be
        /// written. One code for both: a fault code is a slot of every node's fault limiter.
        UpdateFailed = 0x0090, "firmware update failed";
    }
}

wire_enum! {
    /// The outcome of an [`Assign`](super::Assign) or a [`Configure`](super::Configure).
    ConfigStatusCode: u8 {
        /// Stored; a node id is in force at once, a bit rate from the next start.
        Stored = 0x00, "stored";
        /// The value is not one the node takes (a node id outside 1..=127, a bit rate it cannot
        /// run).
        BadValue = 0x01, "value refused";
        /// The configuration page could not be written: nothing changed.
        StoreFailed = 0x02, "could not be stored";
        /// The node has nowhere to keep its configuration (a `pab-node` without --store keeps
        /// it until it exits): in force, not stored.
        NotStored = 0x03, "in force until restart: the node has no store";
        /// A table transfer or a save is in progress: try again when it ends.
        Busy = 0x04, "busy: a transfer or save is in progress";
        /// The node does not set this itself: a Linux node's bit rate is its interface's
        /// (`ip link set can0 type can bitrate R`).
        Unsupported = 0x05, "not this node's to set (a Linux node's bit rate is its interface's)";
    }
}

wire_enum! {
    /// What an [`UpdateStatus`](super::UpdateStatus) says of a firmware update (its byte 0):
    /// an answer to an UpdateTransfer message, or a report at start.
    UpdateStatusCode: u8 {
        /// A Begin was admitted: send chunks from offset 0. Value: the largest chunk the node
        /// takes, bytes.
        Ready = 1, "ready: send chunks from offset 0";
        /// A chunk was written. Offset: the next byte expected; value: the running CRC-32.
        Ack = 2, "chunk written";
        /// The image is complete, its CRC matched, and the bootloader was asked to check and
        /// swap it: the node restarts now.
        Committed = 3, "committed: the node restarts to swap the image in";
        /// The image was refused (value: the refusal's code,
        /// [`crate::update::UpdateRefusal::code`], 1-7): after a Begin whose trailer is refused,
        /// or at start when the bootloader refused the image.
        Refused = 4, "image refused";
        /// A chunk not at the offset expected. Offset: the one expected; value: the running
        /// CRC-32.
        OutOfOrder = 5, "chunk out of order";
        /// A Commit whose CRC or length differs from what was received. Offset and value: the
        /// node's.
        Mismatch = 6, "CRC or length mismatch";
        /// The update partition could not be written. Offset: where.
        FlashError = 7, "update partition could not be written";
        /// A Chunk or Commit without a Begin (or after the session timed out or was aborted).
        NoSession = 8, "no update session";
        /// At start: the bootloader checked and swapped in a new image, which now runs (value 0).
        Swapped = 9, "new image swapped in and running";
        /// The node cannot take updates (it has no update partition).
        Unsupported = 10, "this node takes no updates";
        /// Another transfer holds the node: a table transfer, or an update from another sender.
        Busy = 11, "busy: another transfer holds the node";
        /// At start: the bootloader accepted the image it was asked to swap in, but the firmware
        /// that runs is another (the image did not confirm itself and was reverted, or a reset
        /// came between the bootloader's verdict and its swap).
        NotRunning = 12, "the image was accepted but does not run (reverted)";
    }
}

wire_enum! {
    /// The outcome of a table transfer, sent to the tool.
    TransferStatusCode: u8 {
        /// The new table is running and stored.
        Applied = 0x00, "applied and stored";
        /// The node already runs this exact table (same version and CRC); nothing changed.
        AlreadyCurrent = 0x01, "already running this table";
        /// The new table is running but could not be stored: it will be lost at reboot.
        AppliedNotStored = 0x02, "applied, but storing failed";
        /// The transfer was cut: a consecutive frame came out of sequence or a new transfer
        /// started before the end.
        Interrupted = 0x10, "transfer interrupted";
        /// The transfer was cut: no consecutive frame within the ISO-TP timeout (N_Cr).
        Timeout = 0x11, "transfer timed out";
        /// The image is larger than this node accepts; refused at the first frame.
        TooLarge = 0x12, "image too large for this node";
        /// The image does not start with a valid header (magic, format, lengths).
        BadHeader = 0x13, "bad image header";
        /// The image is for another node id.
        WrongNode = 0x14, "image is for another node";
        /// The image is older than the running table (or the same version with other contents).
        OlderVersion = 0x15, "image is not newer than the running table";
        /// The image's CRC does not match its bytes.
        CrcMismatch = 0x16, "CRC mismatch";
        /// The image's table is invalid or exceeds this node's capacities.
        InvalidTable = 0x17, "table refused by the loader";
        /// A transfer from another source is in progress.
        Busy = 0x18, "another transfer is in progress";
        /// The image's MAC does not verify (wrong key, or bytes changed): the node has a key
        /// and takes only images the key's holder sent for this transfer.
        Unauthenticated = 0x19, "image not authenticated";
    }
}

/// Detail byte 0 of a [`FaultCode::BadStoredTable`] fault when no image reached the checks: the
/// store itself could not be read. Byte 1 is then a [`StoreFailure`]. Not a
/// [`TransferStatusCode`] (those stay below 0x80).
pub const STORE_UNREADABLE: u8 = 0xFF;

wire_enum! {
    /// Why the store could not be read at boot: detail byte 1 of a [`FaultCode::BadStoredTable`]
    /// fault whose byte 0 is [`STORE_UNREADABLE`].
    StoreFailure: u8 {
        /// The medium could not be read: a flash driver error; on Linux, a path that is not a
        /// regular file (a directory, a FIFO, a device) or that the node may not read.
        Read = 0x01, "the store could not be read";
        /// The stored image is larger than this node takes (on Linux: a file over the limit).
        TooLarge = 0x02, "the stored image is too large for this node";
        /// Images were committed, but no stored copy verifies.
        Corrupt = 0x03, "no stored copy verifies";
        /// Any other store failure (an invalid flash layout, for instance).
        Other = 0x04, "the store failed";
    }
}

wire_enum! {
    /// Why a configuration message was refused: detail byte 0 of an
    /// [`FaultCode::Unauthenticated`] fault.
    AuthFailure: u8 {
        /// The node has a key and the message carries no tag (its plain form).
        Missing = 0x01, "no tag, and the node has a key";
        /// The tag does not verify (wrong key, or content changed).
        BadTag = 0x02, "wrong tag";
        /// No challenge outstanding, or it expired (1 s), or it was already used.
        Stale = 0x03, "no fresh challenge";
        /// A configuration command sent to every node (0xFF): a keyed node takes them only
        /// addressed to itself, because each tag is over one node's challenge.
        Broadcast = 0x04, "broadcast configuration refused";
        /// More tag checks than the node makes per second (200): refused unchecked.
        RateLimited = 0x05, "too many tag checks";
        /// A first frame of a transfer that no valid TransferOpen announced (or of another
        /// length): ignored, and a transfer in progress continues.
        Unopened = 0x06, "transfer not opened";
        /// A table transfer from a source other than the tool (0).
        NotTool = 0x07, "transfer from a source other than the tool";
        /// The node's key page is invalid: it accepts no configuration at all.
        Locked = 0x08, "configuration locked: key page invalid";
        /// A tagged message (or a TransferOpen) to a node without a key.
        NoKey = 0x09, "tagged message to a node without a key";
        /// A consecutive frame out of sequence during an opened transfer: ignored.
        Sequence = 0x0A, "consecutive frame out of sequence ignored";
        /// A coordination frame (Gates, BLE claim, filter command) whose seal does not verify
        /// on a keyed node: forged, replayed (its freshness not above the last accepted from
        /// that sender), or sealed under another key. Not applied.
        BadSeal = 0x0B, "seal does not verify";
        /// A coordination frame on a keyed node that no seal followed (within 0.5 s, or before
        /// room was needed for others): not applied.
        Unsealed = 0x0C, "no seal";
        /// A seal from a sender whose freshness the keyed node does not know yet (its first, or
        /// the first after the sender restarted): not applied; the node asked the sender.
        Unsynced = 0x0D, "sender not synchronised yet";
    }
}

wire_enum! {
    /// The answer to a schema message ([`super::SchemaAck`] byte 0): accepted, or why it was
    /// refused (a refused schema changes nothing).
    SchemaOutcome: u8 {
        /// Queued, or waiting for the next tick on the high-priority channel.
        Accepted = 0x00, "accepted";
        /// Not postcard's encoding of a schema (or more reactions than a schema holds), or of
        /// limits on the limits channel.
        Malformed = 0x01, "not a schema's (or limits') encoding";
        /// Bytes after the schema.
        TrailingBytes = 0x02, "bytes after the schema";
        /// An id from 0xFF00 up: those name the server's own schemas.
        ReservedId = 0x03, "id reserved for the server's own schemas (0xFF00 and up)";
        /// An axis index of 6 or more.
        BadAxis = 0x04, "axis index of 6 or more";
        /// A sensor index of 8 or more.
        BadSensor = 0x05, "sensor index of 8 or more";
        /// A coordinate, speed, distance or time beyond ±500 m (µm, µrad).
        OutOfRange = 0x06, "value beyond ±500 m (µm, µrad)";
        /// An action that would never progress.
        Degenerate = 0x07, "action that would never progress (speed 0, no direction, pitch 0)";
        /// A reaction names an innate schema the board does not have.
        UnknownInnate = 0x08, "names an innate schema the board does not have";
        /// The queue is full: refused, nothing overwritten.
        QueueFull = 0x09, "queue full (8): refused, nothing overwritten";
        /// A high-priority schema is already waiting for the next tick.
        Busy = 0x0A, "a high-priority schema is already waiting for the next tick";
        /// The ISO-TP message is longer than a channel byte, the largest schema and a MAC (273
        /// bytes): refused at its first frame.
        TooLong = 0x0B, "message longer than 273 bytes";
        /// The message's channel byte names neither the queue (0), the high-priority channel
        /// (1 in its bits 0-1, the stop number in bits 2-7) nor the limits (2).
        BadChannel = 0x0C, "channel byte neither the queue, the high-priority channel nor the limits";
        /// On a node with a key: the message's MAC does not verify (another key, or a message
        /// changed in flight).
        Unauthenticated = 0x0D, "the message's MAC does not verify (a node with a key)";
        /// The node's table runs no schema server.
        NoServer = 0x0E, "the node's table runs no schema server";
        /// A high-priority schema that names another stop number than the server's latest: sent
        /// before the client saw a stop, it must not leave it (SchemaAck byte 5 is the latest).
        StopNotAcknowledged = 0x0F, "names another stop than the latest: acknowledge the stop first";
        /// The transfer did not complete within its budget (1 s + 10 ms per consecutive frame),
        /// or a consecutive frame came later than N_Cr: the slot is free again.
        TimedOut = 0x10, "transfer timed out";
        /// Limits on the limits channel looser than the table's somewhere, with other joints than
        /// the table's, or inconsistent (a lower bound above its upper one, a force limit of 0).
        Looser = 0x11, "limits looser than the table's, or inconsistent";
    }
}

wire_enum! {
    /// A safety event of the schema server ([`super::SchemaTransition`] detail,
    /// [`super::SchemaState`] byte 3, the [`FaultCode::SchemaSafety`] fault's byte 0): the
    /// numbers of `pab_core::schema::Safety`.
    SchemaSafety: u8 {
        /// An emergency-stop frame arrived.
        EmergencyStop = 0, "emergency stop";
        /// The pose, the wrench or a sensor the reactions read is stale.
        StaleSensor = 1, "sensor stale";
        /// The pose or the attractor went farther outside the workspace.
        Limit = 2, "workspace limit";
        /// The force or torque is above the board's safety limit.
        Force = 3, "force limit";
        /// The schema ran longer than its budget.
        Watchdog = 4, "watchdog";
        /// A tick came later than the board's overrun bound.
        Overrun = 5, "loop overrun";
        /// The measured pose jumped farther than the drive can move.
        ImplausibleSensor = 6, "implausible pose";
        /// A joint went farther outside its range.
        JointLimit = 7, "joint limit";
        /// The pose's translation or rotation, or a joint, moved faster than its limit.
        Speed = 8, "speed limit";
    }
}

wire_enum! {
    /// The channel of a schema message (its byte 0; [`super::SchemaAck`] byte 1).
    SchemaChannel: u8 {
        /// The queue: run after the schemas before it.
        Queue = 0, "queue";
        /// The high-priority channel: installed at the next tick, replacing the running schema
        /// and ending a fault.
        HighPriority = 1, "high-priority channel";
        /// The limits in force ([`crate::schema::Limits`]): a run-time command that tightens
        /// the table's bounds (or sets them back), never looser.
        Limits = 2, "limits";
    }
}

wire_enum! {
    /// What ended a schema ([`super::SchemaTransition`] byte 4).
    SchemaTrigger: u8 {
        /// A schema arrived on the high-priority channel.
        HighPriority = 0, "high-priority channel";
        /// An abort (service 0x19).
        Abort = 1, "abort";
        /// A safety event (the detail byte says which).
        Safety = 2, "safety event";
        /// A reaction of the ended schema (the detail byte is its index in the table).
        Reaction = 3, "reaction";
    }
}

wire_enum! {
    /// Where an installed schema came from ([`super::SchemaTransition`] byte 6,
    /// [`super::SchemaState`] byte 2): `pab_core::schema::Origin`.
    SchemaOrigin: u8 {
        /// The board's own: an innate schema, or a safety recovery.
        Innate = 0, "innate";
        /// The client's queue (or the wait for it).
        Queue = 1, "queue";
        /// The high-priority channel (or the wait for it).
        HighPriority = 2, "high-priority";
    }
}

impl TransferStatusCode {
    /// Whether the new table is running after this outcome.
    pub const fn is_success(self) -> bool {
        matches!(
            self,
            TransferStatusCode::Applied
                | TransferStatusCode::AlreadyCurrent
                | TransferStatusCode::AppliedNotStored
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_are_unique() {
        for state in NodeState::ALL {
            assert_eq!(NodeState::from_code(state.code()), Some(*state));
        }
        for code in FaultCode::ALL {
            assert_eq!(FaultCode::from_code(code.code()), Some(*code));
        }
        for failure in StoreFailure::ALL {
            assert_eq!(StoreFailure::from_code(failure.code()), Some(*failure));
        }
        assert!(TransferStatusCode::from_code(STORE_UNREADABLE).is_none());
        for failure in AuthFailure::ALL {
            assert_eq!(AuthFailure::from_code(failure.code()), Some(*failure));
        }
        for status in TransferStatusCode::ALL {
            assert_eq!(TransferStatusCode::from_code(status.code()), Some(*status));
        }
        for outcome in SchemaOutcome::ALL {
            assert_eq!(SchemaOutcome::from_code(outcome.code()), Some(*outcome));
        }
        for safety in SchemaSafety::ALL {
            assert_eq!(SchemaSafety::from_code(safety.code()), Some(*safety));
        }
        for trigger in SchemaTrigger::ALL {
            assert_eq!(SchemaTrigger::from_code(trigger.code()), Some(*trigger));
        }
        for origin in SchemaOrigin::ALL {
            assert_eq!(SchemaOrigin::from_code(origin.code()), Some(*origin));
        }
        for channel in SchemaChannel::ALL {
            assert_eq!(SchemaChannel::from_code(channel.code()), Some(*channel));
        }
        for status in UpdateStatusCode::ALL {
            assert_eq!(UpdateStatusCode::from_code(status.code()), Some(*status));
        }
        assert_eq!(UpdateStatusCode::from_code(0), None);
        assert_eq!(UpdateStatusCode::from_code(13), None);
        assert_eq!(SchemaOutcome::from_code(0x12), None);
        assert_eq!(SchemaSafety::from_code(9), None);
        assert_eq!(SchemaSafety::from_code(0xFF), None);
        assert_eq!(SchemaTrigger::from_code(4), None);
        assert_eq!(SchemaOrigin::from_code(3), None);
        assert_eq!(SchemaChannel::from_code(3), None);
        assert_eq!(NodeState::from_code(3), None);
        assert_eq!(FaultCode::from_code(0), None);
        assert_eq!(TransferStatusCode::from_code(0xFF), None);
    }
}
