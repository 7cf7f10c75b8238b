//! Building an arbiter from a table: in place, where it stays, the table validated once; then
//! its run-time form (ports, slots, decision steps, filter index, value ports, groups).

use heapless::Vec;

use super::{Arbiter, Port, PortSet, Slot};
use crate::ble::Eligibility;
use crate::decay::Decay;
use crate::decision::{self, NodeRef, Step};
#[cfg(feature = "dynamics")]
use crate::dynamics::{GroupRun, SourceState};
use crate::hbba::filters::{Throttles, UNFILTERED};
use crate::index::FilterIndex;
use crate::integrator::Integrator;
use crate::table::{Connection, Table, TableError, Verdict};
use crate::value_port::{MAX_VALUE_CONNECTIONS, ValueSlot, ValueState};

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// Starts arbitrating with `table`, every connection at S = 0 and inactive.
    ///
    /// Validates the table again (it is cheap, and a `Table` can be deserialized without the
    /// loader), and fails with the first [`TableError`] found. Costs one pass over the table and
    /// the sort of its filters. [`Arbiter::new_in`] builds it in a place of the caller's instead.
    pub fn new(table: Table<PORTS, CONNECTIONS, NODES>) -> Result<Self, TableError> {
        let mut slot = None;
        match Self::new_in::<TableError, (), TableError>(&mut slot, |blank| {
            *blank = table;
            Ok(())
        }) {
            Ok(Ok(_)) => slot.ok_or(TableError::TooManyNodes),
            Ok(Err(error)) | Err(error) => Err(error),
        }
    }

    /// [`Arbiter::new`], built in `slot` with the table that `fill` writes into the (empty)
    /// table there, and left there: whatever `slot` held is replaced, by `None` when `fill`
    /// fails (its error, outside) or the table is refused (inside). Returns what `fill` did and
    /// the arbiter; an invalid table is refused with the verdict `R` ([`TableError`] says what is
    /// wrong, [`Refused`](crate::Refused) only that something is). For a caller with a place for
    /// it, as a node has for the arbiter that replaces its running one, and a table to decode:
    /// [`crate::image::load_into_as`].
    // Built where it stays, its table decoded where it stays: returned by value, the arbiter
    // was in the frames of both `new` and the node's loader (the table three times there), 87
    // KB of stack, more than the NUCLEO-G474RE had left with the schema server, and each move
    // was a copy of 10 or 25 KB. Left to be inlined: kept out of line, the loader's error went
    // through memory to the node, 256 bytes more of the NUCLEO-G474RE's flash.
    pub fn new_in<R: Verdict, T, E>(
        slot: &mut Option<Self>,
        fill: impl FnOnce(&mut Table<PORTS, CONNECTIONS, NODES>) -> Result<T, E>,
    ) -> Result<Result<(T, &mut Self), R>, E> {
        Self::build_in(slot, fill, true)
    }

    /// [`Arbiter::new_in`] with the table of the image `bytes`, decoded in place
    /// ([`crate::image::load_into_as`]): the image's header and the arbiter. The loader refuses
    /// an invalid table (its [`LoadError::Table`](crate::image::LoadError::Table)), so the
    /// table is not validated a second time; the verdict inside is the one [`Arbiter::new_in`]
    /// gives a table it cannot build.
    // The loader's validation is the arbiter's: a second pass (a call and its refusal) was 16
    // bytes of the NUCLEO-G474RE's flash.
    pub fn load_in<'a, R: Verdict>(
        slot: &'a mut Option<Self>,
        bytes: &[u8],
    ) -> Result<Result<(crate::image::Header, &'a mut Self), R>, crate::image::LoadError<R>> {
        Self::build_in(
            slot,
            |table| crate::image::load_into_as::<PORTS, CONNECTIONS, NODES, R>(bytes, table),
            false,
        )
    }

    /// [`Arbiter::new_in`], the table validated again only if `validate` (a table `fill` has
    /// validated is valid).
    #[inline(always)]
    fn build_in<R: Verdict, T, E>(
        slot: &mut Option<Self>,
        fill: impl FnOnce(&mut Table<PORTS, CONNECTIONS, NODES>) -> Result<T, E>,
        validate: bool,
    ) -> Result<Result<(T, &mut Self), R>, E> {
        // Part by part in place (the literal: empty lists are their lengths), not built aside
        // and moved: each move was code, reaching the parts at large offsets in a frame.
        let arbiter = slot.insert(Arbiter {
            ports: Vec::new(),
            index: FilterIndex::empty(),
            slots: Vec::new(),
            steps: Vec::new(),
            value_ports: PortSet::default(),
            values: Vec::new(),
            value_slots: Vec::new(),
            groups: Vec::new(),
            #[cfg(feature = "dynamics")]
            runs: Vec::new(),
            #[cfg(feature = "dynamics")]
            sources: Vec::new(),
            throttles: Throttles::default(),
            table: Table::new(),
        });
        let filled = match fill(&mut arbiter.table) {
            Ok(filled) => filled,
            Err(error) => {
                *slot = None;
                return Err(error);
            }
        };
        let checked = if validate {
            arbiter.table.check::<R>()
        } else {
            Ok(())
        };
        let built = match checked {
            Ok(()) => {
                arbiter.throttles = Throttles::new(arbiter.table.filters());
                arbiter
                    .build()
                    .ok_or_else(|| R::refuse(|| TableError::TooManyNodes))
            }
            Err(error) => Err(error),
        };
        if let Err(error) = built {
            *slot = None;
            return Ok(Err(error));
        }
        Ok(slot
            .as_mut()
            .map(|arbiter| (filled, arbiter))
            .ok_or_else(|| R::refuse(|| TableError::TooManyNodes)))
    }

    /// Builds the run-time form of `self.table`, which [`Table::validate`] accepted, into this
    /// arbiter's empty parts. Every `?` below but one is a capacity that a validated table
    /// cannot exceed (its own, which this arbiter shares; at most 16 ports of 32 connections;
    /// the value ports' and groups' fixed ones) or a parameter it has checked. They are kept (a
    /// `None`, never a panic) but no longer each with an error of its own: that was 108 bytes
    /// of the NUCLEO-G474RE's flash for paths no table takes. The one a validated table can
    /// take is more than 2^16 decision nodes before a port (a capacity `NODES` beyond 65 536;
    /// the steps' positions are `u16`): [`Arbiter::new`]'s [`TableError::TooManyNodes`], as
    /// before.
    fn build(&mut self) -> Option<()> {
        let Arbiter {
            ports,
            index,
            slots,
            steps,
            value_ports,
            values,
            value_slots,
            groups,
            #[cfg(feature = "dynamics")]
            runs,
            #[cfg(feature = "dynamics")]
            sources,
            throttles: _,
            table,
        } = self;
        for (position, parts) in table.parts().enumerate() {
            // At most 16 ports (a table's `CAPACITIES_FIT`): the cast keeps the index whole.
            let port = position as u8;
            let (record, views, nodes, roots) = parts?;
            let first_connection = u16::try_from(slots.len()).ok()?;
            push_slots(slots, views, port)?;
            let first_step = u16::try_from(steps.len()).ok()?;
            let end = usize::from(first_step).saturating_add(nodes.len());
            steps.resize(end, Step::NOBODY).ok()?;
            decision::compile(nodes, steps.get_mut(usize::from(first_step)..)?);
            let run = Port {
                first_connection,
                connections: u8::try_from(views.len()).ok()?,
                first_step,
                steps: u16::try_from(nodes.len()).ok()?,
                root: record.root(),
                // Idle (`Port::idle`): inactive, no connection flagged, nobody selected.
                flagged: 0,
                steady: 0,
                from: 0,
                until: u64::MAX,
                lapsed_from: 0,
                lapsed_until: u64::MAX,
                decided_for: 0,
                decided: None,
                external: 0,
            };
            ports.push(run).ok()?;
            if let Some(spec) = record.value() {
                let first = u8::try_from(value_slots.len()).ok()?;
                let own = slots.get(usize::from(first_connection)..).unwrap_or(&[]);
                push_value_slots(value_slots, own, roots)?;
                let count = u8::try_from(roots.len()).ok()?;
                values
                    .push(ValueState::new(port, first, count, spec))
                    .ok()?;
                *value_ports = value_ports.with(port);
            }
        }
        index.build(table.connections())?;
        // Validated: the filtered connections exist, at most MAX_FILTERED (< UNFILTERED) of them.
        for (position, &connection) in table.filters().connections.iter().enumerate() {
            if let Some(slot) = slots.get_mut(usize::from(connection)) {
                slot.filter = position as u8;
            }
        }
        // Validated with the table (`Group::validate`): `Eligibility::new`'s checks again were
        // 28 bytes of the NUCLEO-G474RE's flash.
        for group in table.groups() {
            groups.push(Eligibility::of(group)).ok()?;
        }
        // Each group started where it lives (`GroupRun::start`; built and moved, it was copied),
        // its parameters validated with the table. The blanks in one `resize`, cleared in
        // place: pushed one at a time they were copied from a 3.4 KiB constant of zeros that
        // LLVM kept in the flash.
        #[cfg(feature = "dynamics")]
        runs.resize(table.dynamics().len(), GroupRun::BLANK).ok()?;
        #[cfg(feature = "dynamics")]
        for (run, spec) in runs.iter_mut().zip(table.dynamics()) {
            run.start(spec);
        }
        // The sources, all unheard, in one `resize`: a push per source was 8 bytes more of the
        // NUCLEO-G474RE's flash.
        #[cfg(feature = "dynamics")]
        sources
            .resize(table.gate_sources().len(), SourceState::new())
            .ok()?;
        Some(())
    }
}

/// A value port's slots, its connections' τ (`own`) with their `roots`, appended to
/// `value_slots`.
// Out of line: inlined into `Arbiter::build`, deep in the node's loader, each slot's fields were
// reached through addresses kept on the stack, 36 bytes more of the NUCLEO-G474RE's flash. Run
// once per value port and table.
#[inline(never)]
fn push_value_slots(
    value_slots: &mut Vec<ValueSlot, MAX_VALUE_CONNECTIONS>,
    own: &[Slot],
    roots: &[NodeRef],
) -> Option<()> {
    for (slot, &root) in own.iter().zip(roots) {
        value_slots.push(ValueSlot::new(slot.tau, root)).ok()?;
    }
    Some(())
}

/// The slots of port `port`, its connections `views` (validated with the table) at S = 0,
/// appended to `slots`.
// Out of line: inlined into `Arbiter::build`, deep in the node's loader, each slot's fields were
// reached through addresses kept on the stack, 72 bytes more of the NUCLEO-G474RE's flash. Run
// once per port and table.
#[inline(never)]
fn push_slots<const CONNECTIONS: usize>(
    slots: &mut Vec<Slot, CONNECTIONS>,
    views: &[Connection],
    port: u8,
) -> Option<()> {
    for (index, connection) in views.iter().enumerate() {
        // `Runtime::new` less the checks `table.validate()` made: they cannot fail again, and
        // inlined a second time they took 160 bytes of the NUCLEO-G474RE's flash. The decay's
        // (τ > 0, validated too) is kept.
        let (tau, reciprocal) = Decay::new(connection.stimulation.decay_us())?.parts();
        let slot = Slot {
            integrator: Integrator::new(),
            reciprocal,
            tau,
            gain: connection.stimulation.gain(),
            rest_us: connection.stimulation.rest_us(),
            port,
            index: u8::try_from(index).ok()?,
            filter: UNFILTERED,
        };
        slots.push(slot).ok()?;
    }
    Some(())
}
