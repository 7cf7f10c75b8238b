//! A node's arbitration table: its ports, their connections and their decisions.
//!
//! This is both the body of a table image (postcard encodes it as it is) and what a node keeps in
//! RAM, so a board needs no second copy to load one. Layout: connections and decision nodes are
//! stored port after port; a port records how many of each it owns, so ranges follow from the
//! counts and cannot overlap.
//!
//! Capacities are const generic parameters: `Table<PORTS, CONNECTIONS, NODES>` holds at most
//! `PORTS` ports (at most [`MAX_PORTS`]), `CONNECTIONS` connections and `NODES` decision nodes over
//! all its ports. The defaults are [`MAX_PORTS`], [`MAX_CONNECTIONS`] and [`MAX_DECISION_NODES`];
//! [`crate::BoardTable`] is the profile for a board with little RAM. The encoding does not depend
//! on the capacities, so one image loads into any table large enough for it.
//!
//! Value ports ([`crate::value_port`]) carry a [`ValueSpec`] in their port record and one decision
//! root per connection, in a list of roots after the decision nodes (value port after value
//! port, in port order); an ordinary port has none.
//!
//! Memory: `size_of::<Table<P, C, N>>()` is about 26·C + 6·N + 32·P bytes (`cargo run -p
//! pab-core --example footprint` tells exactly, docs/figures.md).

use core::ops::Range;

use heapless::Vec;
use serde::{Deserialize, Serialize};

use crate::ble::{self, Group, GroupError, MAX_GROUPS, MAX_PEERS};
use crate::consumer::{Consumer, OutputIdError};
use crate::decision::{self, DecisionError, DecisionNode, NodeRef};
use crate::dynamics::DynamicsError;
use crate::dynamics::{GateLink, GateSource, GroupSpec, TABLE_GROUPS, TABLE_LINKS, TABLE_SOURCES};
use crate::filter::{Filter, FilterError};
use crate::hbba::filters::{FiltersError, MessageFilters};
use crate::integrator::{ParamError, Stimulation};
use crate::value_port::{MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS, ValueError, ValueSpec};
use crate::{MAX_CONNECTIONS, MAX_CONNECTIONS_PER_PORT, MAX_DECISION_NODES, MAX_PORTS};

/// One connection: which frames feed it and how they stimulate it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Connection {
    /// The frames that feed it.
    pub filter: Filter,
    /// ⟨σ, τ, τr⟩.
    pub stimulation: Stimulation,
}

/// One port: how many connections and decision nodes it owns, where its decision starts, who
/// receives what it delivers, and for a value port what it combines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Port {
    connections: u8,
    nodes: u16,
    root: NodeRef,
    consumer: Consumer,
    value: Option<ValueSpec>,
}

/// A port of a table, with its slices.
#[derive(Clone, Copy, Debug)]
pub struct PortView<'a> {
    /// The connections of the port; a connection's index here is its index in rules and masks.
    pub connections: &'a [Connection],
    /// The port's decision nodes.
    pub nodes: &'a [DecisionNode],
    /// The entry of the port's decision.
    pub root: NodeRef,
    /// Who receives the frames the port delivers.
    pub consumer: Consumer,
    /// For a value port, what it reads and how it combines; `None` for an ordinary port.
    pub value: Option<ValueSpec>,
    /// For a value port, each connection's decision root (as many as connections); empty for
    /// an ordinary port.
    pub roots: &'a [NodeRef],
}

/// A node's arbitration table, with room for `PORTS` ports, `CONNECTIONS` connections and `NODES`
/// decision nodes. Build one with [`Table::push_port`] or load one from an image with
/// [`crate::image::load`]; both validate everything.
///
/// `PORTS` must be at most [`MAX_PORTS`] (ports are bits of a `u16`): a larger value is a
/// compile-time error where [`Table::new`] or [`Table::validate`] is used. Each port has at most
/// [`MAX_CONNECTIONS_PER_PORT`] connections whatever `CONNECTIONS` is.
///
/// ```
/// let board: pab_core::BoardTable = pab_core::Table::new();
/// assert_eq!(board.port_count(), 0);
/// ```
///
/// ```compile_fail
/// // 17 ports do not fit a `PortSet`: refused when the code is built.
/// let table: pab_core::Table<17, 8, 8> = pab_core::Table::new();
/// ```
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Table<
    const PORTS: usize = MAX_PORTS,
    const CONNECTIONS: usize = MAX_CONNECTIONS,
    const NODES: usize = MAX_DECISION_NODES,
> {
    ports: Vec<Port, PORTS>,
    connections: Vec<Connection, CONNECTIONS>,
    nodes: Vec<DecisionNode, NODES>,
    roots: Vec<NodeRef, CONNECTIONS>,
    groups: Vec<Group, { ble::TABLE_GROUPS }>,
    dynamics: Vec<GroupSpec, TABLE_GROUPS>,
    gate_sources: Vec<GateSource, TABLE_SOURCES>,
    gate_links: Vec<GateLink, TABLE_LINKS>,
    filters: MessageFilters,
    /// Format 7: the schema server the node runs, if any.
    #[cfg(feature = "schema")]
    schema: Option<crate::schema::Setup>,
}

/// Why a table was refused. Ports and connections are numbered from 0, connections within their
/// port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum TableError {
    /// More ports than the table's capacity `PORTS`.
    TooManyPorts,
    /// More connections in all than the table's capacity `CONNECTIONS`.
    TooManyConnections,
    /// More decision nodes in all than the table's capacity `NODES`.
    TooManyNodes,
    /// [`Table::set_consumer`] named a port the table does not have.
    NoSuchPort {
        /// The port.
        port: u8,
    },
    /// A port's consumer re-publishes on an identifier that does not fit its format.
    Consumer {
        /// The port.
        port: u8,
        /// What is wrong.
        error: OutputIdError,
    },
    /// A port has more than [`MAX_CONNECTIONS_PER_PORT`] connections.
    PortTooWide {
        /// The port.
        port: u8,
    },
    /// The ports' connection counts do not add up to the number of connections.
    ConnectionCountMismatch,
    /// The ports' node counts do not add up to the number of decision nodes.
    NodeCountMismatch,
    /// The value ports' connection counts do not add up to the number of roots.
    RootCountMismatch,
    /// More value ports than [`MAX_VALUE_PORTS`].
    TooManyValuePorts,
    /// More connections of value ports in all than [`MAX_VALUE_CONNECTIONS`].
    TooManyValueConnections,
    /// The competitive-dynamics part ([`crate::dynamics`]).
    Dynamics(DynamicsError),
    /// The HBBA message filters ([`crate::hbba::filters`]).
    Filters(FiltersError),
    /// The schema server's set-up ([`crate::schema::Setup`]).
    #[cfg(feature = "schema")]
    Schema(crate::schema::SetupError),
    /// More BLE groups than [`MAX_GROUPS`].
    TooManyGroups,
    /// A BLE group is invalid ([`crate::ble`]).
    Group {
        /// The group's position in the table.
        group: u8,
        /// What is wrong.
        error: GroupError,
    },
    /// A BLE group's claim connection has a filter other than [`ble::CLAIM_SLOT_FILTER`] (it
    /// would be fed by frames: a claim's activity is the group's, never an integrator's).
    ClaimFilter {
        /// The port.
        port: u8,
        /// The connection within the port.
        connection: u8,
    },
    /// A value port is invalid.
    Value {
        /// The port.
        port: u8,
        /// What is wrong.
        error: ValueError,
    },
    /// A connection's stimulation parameters are invalid.
    Parameter {
        /// The port.
        port: u8,
        /// The connection within the port.
        connection: u8,
        /// What is wrong.
        error: ParamError,
    },
    /// A connection's filter is invalid.
    Filter {
        /// The port.
        port: u8,
        /// The connection within the port.
        connection: u8,
        /// What is wrong.
        error: FilterError,
    },
    /// A port's decision diagram is invalid.
    Decision {
        /// The port.
        port: u8,
        /// What is wrong.
        error: DecisionError,
    },
}

impl core::fmt::Display for TableError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TableError::TooManyPorts => f.write_str("more ports than the table holds"),
            TableError::TooManyConnections => f.write_str("more connections than the table holds"),
            TableError::TooManyNodes => f.write_str("more decision nodes than the table holds"),
            TableError::NoSuchPort { port } => write!(f, "there is no port {port}"),
            TableError::Consumer { port, error } => write!(f, "port {port}: consumer: {error}"),
            TableError::PortTooWide { port } => {
                write!(
                    f,
                    "port {port} has more than {MAX_CONNECTIONS_PER_PORT} connections"
                )
            }
            TableError::ConnectionCountMismatch => {
                f.write_str("the ports' connection counts do not add up")
            }
            TableError::NodeCountMismatch => f.write_str("the ports' node counts do not add up"),
            TableError::RootCountMismatch => {
                f.write_str("the value ports' connection counts do not add up to their roots")
            }
            TableError::TooManyValuePorts => {
                write!(f, "more than {MAX_VALUE_PORTS} value ports")
            }
            TableError::TooManyValueConnections => write!(
                f,
                "more than {MAX_VALUE_CONNECTIONS} connections on value ports in all"
            ),
            TableError::Value { port, error } => write!(f, "port {port}: {error}"),
            TableError::TooManyGroups => write!(f, "more than {MAX_GROUPS} BLE groups"),
            TableError::Dynamics(error) => write!(f, "{error}"),
            TableError::Filters(error) => write!(f, "{error}"),
            #[cfg(feature = "schema")]
            TableError::Schema(error) => write!(f, "{error}"),
            TableError::Group { group, error } => write!(f, "BLE group {group}: {error}"),
            TableError::ClaimFilter { port, connection } => write!(
                f,
                "port {port}, connection {connection}: a BLE claim must have the claim filter"
            ),
            TableError::Parameter {
                port,
                connection,
                error,
            } => write!(f, "port {port}, connection {connection}: {error}"),
            TableError::Filter {
                port,
                connection,
                error,
            } => write!(f, "port {port}, connection {connection}: {error}"),
            TableError::Decision { port, error } => write!(f, "port {port}: {error}"),
        }
    }
}

impl core::error::Error for TableError {}

/// What the table's checks ([`Table::check`]) return for a table they refuse: [`TableError`],
/// what is wrong and where, or [`Refused`], only that something is. One set of checks serves
/// both.
pub trait Verdict: Sized {
    /// The verdict for the refusal `error` describes; `error` is called only by verdicts that
    /// keep it.
    fn refuse(error: impl FnOnce() -> TableError) -> Self;
}

impl Verdict for TableError {
    #[inline(always)]
    fn refuse(error: impl FnOnce() -> TableError) -> Self {
        error()
    }
}

/// A table refused, without why: the verdict of the boards, which answer one transfer status
/// for any invalid table. Building and packing the [`TableError`] nobody reads there took 628
/// bytes of the NUCLEO-G474RE's flash with the schema server, 624 without.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Refused;

impl Verdict for Refused {
    #[inline(always)]
    fn refuse(_: impl FnOnce() -> TableError) -> Self {
        Refused
    }
}

impl core::fmt::Display for Refused {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("the table breaks a rule")
    }
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize> Default
    for Table<PORTS, CONNECTIONS, NODES>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Table<PORTS, CONNECTIONS, NODES>
{
    /// Evaluated (at compile time) wherever a table of these capacities is created or validated.
    const CAPACITIES_FIT: () = assert!(
        PORTS <= MAX_PORTS,
        "a table has at most MAX_PORTS (16) ports: PortSet is a u16"
    );

    /// The capacities, as (ports, connections, decision nodes).
    pub const CAPACITY: (usize, usize, usize) = (PORTS, CONNECTIONS, NODES);

    /// A table without ports. Costs nothing; fails to compile if `PORTS` exceeds [`MAX_PORTS`].
    pub const fn new() -> Self {
        let () = Self::CAPACITIES_FIT;
        Table {
            ports: Vec::new(),
            connections: Vec::new(),
            nodes: Vec::new(),
            roots: Vec::new(),
            groups: Vec::new(),
            dynamics: Vec::new(),
            gate_sources: Vec::new(),
            gate_links: Vec::new(),
            filters: MessageFilters {
                connections: Vec::new(),
                profiles: Vec::new(),
            },
            #[cfg(feature = "schema")]
            schema: None,
        }
    }

    /// Appends a port whose frames go to [`Consumer::Local`] (see [`Table::set_consumer`]).
    /// Validates the connections and the decision before changing anything: on error the table is
    /// unchanged. Fails with [`TableError::TooManyPorts`], [`TableError::TooManyConnections`] or
    /// [`TableError::TooManyNodes`] when the capacities would be exceeded, and with the
    /// connection's or decision's error when one is invalid. Costs one pass over the new
    /// connections and nodes.
    pub fn push_port(
        &mut self,
        connections: &[Connection],
        nodes: &[DecisionNode],
        root: NodeRef,
    ) -> Result<(), TableError> {
        self.push(connections, nodes, root, None, &[])
    }

    /// Appends a value port ([`crate::value_port`]) whose frames go to [`Consumer::Local`]:
    /// `roots[i]` is connection i's decision root (it contributes while the diagram entered
    /// there answers "i delivers"). Validates as [`Table::push_port`] does, and the spec, the
    /// roots (one per connection, each valid within `nodes`) and the value capacities
    /// ([`TableError::TooManyValuePorts`], [`TableError::TooManyValueConnections`]); on error
    /// the table is unchanged.
    pub fn push_value_port(
        &mut self,
        connections: &[Connection],
        nodes: &[DecisionNode],
        spec: ValueSpec,
        roots: &[NodeRef],
    ) -> Result<(), TableError> {
        if roots.len() != connections.len() {
            return Err(TableError::RootCountMismatch);
        }
        let (ports, value_connections) = self.value_usage();
        if ports >= MAX_VALUE_PORTS {
            return Err(TableError::TooManyValuePorts);
        }
        if value_connections.saturating_add(connections.len()) > MAX_VALUE_CONNECTIONS {
            return Err(TableError::TooManyValueConnections);
        }
        self.push(connections, nodes, NodeRef::NOBODY, Some(spec), roots)
    }

    /// Appends a BLE group ([`crate::ble`]): its ports and claim connections must exist already
    /// (push the ports first), each claim connection with [`ble::CLAIM_SLOT_FILTER`]. On error
    /// the table is unchanged.
    pub fn push_group(&mut self, group: Group) -> Result<(), TableError> {
        self.groups
            .push(group)
            .map_err(|_| TableError::TooManyGroups)?;
        // One set of checks for the loader and the builder: the whole table again (a workstation
        // pushes a handful of groups, and the boards keep one copy of the code).
        if let Err(error) = self.validate() {
            self.groups.pop();
            return Err(error);
        }
        Ok(())
    }

    /// The BLE groups the node is in.
    pub fn groups(&self) -> &[Group] {
        &self.groups
    }

    /// Appends the competitive-dynamics part ([`crate::dynamics`]): the groups the node runs, the
    /// groups whose gates it reads and the gate connections (which must exist already, each with
    /// [`crate::dynamics::GATE_SLOT_FILTER`]). On error the table is unchanged.
    #[cfg(feature = "dynamics")]
    pub fn push_dynamics(
        &mut self,
        groups: &[GroupSpec],
        sources: &[GateSource],
        links: &[GateLink],
    ) -> Result<(), TableError> {
        let saved = (
            self.dynamics.len(),
            self.gate_sources.len(),
            self.gate_links.len(),
        );
        let pushed = groups
            .iter()
            .try_for_each(|g| self.dynamics.push(g.clone()).map_err(|_| ()))
            .and_then(|()| {
                sources
                    .iter()
                    .try_for_each(|&s| self.gate_sources.push(s).map_err(|_| ()))
            })
            .and_then(|()| {
                links
                    .iter()
                    .try_for_each(|&l| self.gate_links.push(l).map_err(|_| ()))
            })
            .map_err(|()| TableError::Dynamics(DynamicsError::TooMany))
            .and_then(|()| self.validate());
        if let Err(error) = pushed {
            self.dynamics.truncate(saved.0);
            self.gate_sources.truncate(saved.1);
            self.gate_links.truncate(saved.2);
            return Err(error);
        }
        Ok(())
    }

    /// The competitive-dynamics groups the node runs.
    pub fn dynamics(&self) -> &[GroupSpec] {
        &self.dynamics
    }

    /// The groups whose gates the node reads.
    pub fn gate_sources(&self) -> &[GateSource] {
        &self.gate_sources
    }

    /// The gate connections.
    pub fn gate_links(&self) -> &[GateLink] {
        &self.gate_links
    }

    /// Sets the HBBA message filters ([`crate::hbba::filters`]): the connections they name must
    /// exist already (push the ports first). On error the table is unchanged.
    pub fn set_filters(&mut self, filters: MessageFilters) -> Result<(), TableError> {
        filters
            .validate(self.connections.len())
            .map_err(TableError::Filters)?;
        self.filters = filters;
        Ok(())
    }

    /// The HBBA message filters.
    pub fn filters(&self) -> &MessageFilters {
        &self.filters
    }

    /// The connections, moved out (the table is left without any): for
    /// [`crate::Arbiter::take_carried`].
    pub(crate) fn take_connections(&mut self) -> Vec<Connection, CONNECTIONS> {
        core::mem::take(&mut self.connections)
    }

    /// The HBBA message filters, moved out (the table is left without any): for
    /// [`crate::Arbiter::take_carried`].
    pub(crate) fn take_filters(&mut self) -> MessageFilters {
        core::mem::take(&mut self.filters)
    }

    /// The dynamics part, as [`Table::validate`] checks it (the loader adds the node id's check).
    #[cfg(feature = "dynamics")]
    fn validate_dynamics<R: Verdict>(&self, node: u8) -> Result<(), R> {
        crate::dynamics::validate_table_part(
            &self.dynamics,
            &self.gate_sources,
            &self.gate_links,
            node,
            &|port, connection| connection_filter(&self.ports, &self.connections, port, connection),
        )
        .map_err(|error| R::refuse(|| TableError::Dynamics(error)))
    }

    /// How many value ports there are, and connections on them.
    fn value_usage(&self) -> (usize, usize) {
        // At most `PORTS` ≤ 16 ports of 255 connections: no overflow.
        self.ports.iter().filter(|port| port.value.is_some()).fold(
            (0, 0),
            |(ports, connections), port| {
                (
                    ports.wrapping_add(1),
                    connections.wrapping_add(usize::from(port.connections)),
                )
            },
        )
    }

    fn push(
        &mut self,
        connections: &[Connection],
        nodes: &[DecisionNode],
        root: NodeRef,
        value: Option<ValueSpec>,
        roots: &[NodeRef],
    ) -> Result<(), TableError> {
        let index = u8::try_from(self.ports.len()).map_err(|_| TableError::TooManyPorts)?;
        let port = Port {
            connections: u8::try_from(connections.len())
                .ok()
                .filter(|&count| usize::from(count) <= MAX_CONNECTIONS_PER_PORT)
                .ok_or(TableError::PortTooWide { port: index })?,
            nodes: u16::try_from(nodes.len()).map_err(|_| TableError::TooManyNodes)?,
            root,
            consumer: Consumer::Local,
            value,
        };
        validate_port(index, &port, connections, nodes, roots)?;
        if self.ports.len() >= PORTS {
            return Err(TableError::TooManyPorts);
        }
        if self.connections.len().saturating_add(connections.len()) > CONNECTIONS {
            return Err(TableError::TooManyConnections);
        }
        if self.nodes.len().saturating_add(nodes.len()) > NODES {
            return Err(TableError::TooManyNodes);
        }
        if self.roots.len().saturating_add(roots.len()) > CONNECTIONS {
            return Err(TableError::TooManyConnections);
        }
        // Capacities were checked above, so none of these can fail.
        self.ports
            .push(port)
            .map_err(|_| TableError::TooManyPorts)?;
        self.connections
            .extend_from_slice(connections)
            .map_err(|_| TableError::TooManyConnections)?;
        self.nodes
            .extend_from_slice(nodes)
            .map_err(|_| TableError::TooManyNodes)?;
        self.roots
            .extend_from_slice(roots)
            .map_err(|_| TableError::TooManyConnections)?;
        Ok(())
    }

    /// Sets who receives what port `port` delivers. Fails with [`TableError::NoSuchPort`] or
    /// [`TableError::Consumer`] (an identifier that does not fit its format), leaving the table
    /// unchanged. Costs a bounds check.
    pub fn set_consumer(&mut self, port: u8, consumer: Consumer) -> Result<(), TableError> {
        consumer
            .validate()
            .map_err(|error| TableError::Consumer { port, error })?;
        let record = self
            .ports
            .get_mut(usize::from(port))
            .ok_or(TableError::NoSuchPort { port })?;
        record.consumer = consumer;
        Ok(())
    }

    /// Checks every count, parameter, filter, consumer and decision. The loader calls it on every
    /// table it decodes; it costs one pass over the connections and one over the nodes.
    pub fn validate(&self) -> Result<(), TableError> {
        self.check()
    }

    /// [`Table::validate`], refusing with the verdict `R`: [`TableError`] says what is wrong,
    /// [`Refused`] only that something is.
    pub fn check<R: Verdict>(&self) -> Result<(), R> {
        let () = Self::CAPACITIES_FIT;
        // What the ports before have not taken of each list.
        let mut connections_left: &[Connection] = &self.connections;
        let mut nodes_left: &[DecisionNode] = &self.nodes;
        let mut roots_left: &[NodeRef] = &self.roots;
        // The value ports and their connections ([`Table::value_usage`]), counted in this pass:
        // a pass of their own was 42 bytes of the NUCLEO-G474RE's flash. At most `PORTS` ≤ 16
        // ports of 255 connections: no overflow.
        let (mut value_ports, mut value_connections) = (0usize, 0usize);
        for (index, port) in self.ports.iter().enumerate() {
            // At most `PORTS` ≤ 16 ports (`CAPACITIES_FIT`): the cast keeps the index whole. A
            // refusal for an index beyond `u8` (none can be) was 20 bytes of the NUCLEO-G474RE's
            // flash.
            let index = index as u8;
            if usize::from(port.connections) > MAX_CONNECTIONS_PER_PORT {
                return Err(R::refuse(|| TableError::PortTooWide { port: index }));
            }
            let connections = take(&mut connections_left, port.connections)
                .ok_or_else(|| R::refuse(|| TableError::ConnectionCountMismatch))?;
            let nodes = take(&mut nodes_left, port.nodes)
                .ok_or_else(|| R::refuse(|| TableError::NodeCountMismatch))?;
            let roots = match port.value {
                Some(_) => {
                    value_ports = value_ports.wrapping_add(1);
                    value_connections =
                        value_connections.wrapping_add(usize::from(port.connections));
                    take(&mut roots_left, port.connections)
                        .ok_or_else(|| R::refuse(|| TableError::RootCountMismatch))?
                }
                None => &[],
            };
            validate_port::<R>(index, port, connections, nodes, roots)?;
            check_claims::<R>(index, connections, &self.groups)?;
        }
        if !connections_left.is_empty() {
            return Err(R::refuse(|| TableError::ConnectionCountMismatch));
        }
        if !nodes_left.is_empty() {
            return Err(R::refuse(|| TableError::NodeCountMismatch));
        }
        if !roots_left.is_empty() {
            return Err(R::refuse(|| TableError::RootCountMismatch));
        }
        if value_ports > MAX_VALUE_PORTS {
            return Err(R::refuse(|| TableError::TooManyValuePorts));
        }
        if value_connections > MAX_VALUE_CONNECTIONS {
            return Err(R::refuse(|| TableError::TooManyValueConnections));
        }
        for (index, group) in self.groups.iter().enumerate() {
            let error = |error| {
                R::refuse(|| TableError::Group {
                    group: u8::try_from(index).unwrap_or(u8::MAX),
                    error,
                })
            };
            group.validate(self.ports.len(), MAX_PEERS).map_err(error)?;
            let number = group.number;
            // The groups before, as a slice: through `take(index)` the search was 32 bytes
            // more of the NUCLEO-G474RE's flash.
            let before = self.groups.get(..index).unwrap_or(&[]);
            if before.iter().any(|g| g.number == number) {
                return Err(error(GroupError::DuplicateGroup { number }));
            }
        }
        #[cfg(feature = "dynamics")]
        self.validate_dynamics::<R>(crate::dynamics::OWN)?;
        self.filters
            .validate(self.connections.len())
            .map_err(|error| R::refuse(|| TableError::Filters(error)))?;
        #[cfg(feature = "schema")]
        if let Some(setup) = &self.schema {
            setup
                .check()
                .map_err(|error| R::refuse(|| TableError::Schema(error)))?;
        }
        Ok(())
    }

    /// The schema server the node runs, if any.
    #[cfg(feature = "schema")]
    pub fn schema(&self) -> Option<&crate::schema::Setup> {
        self.schema.as_ref()
    }

    /// Sets (or removes) the schema server the node runs. Checked with the rest of the table by
    /// [`Table::validate`].
    #[cfg(feature = "schema")]
    pub fn set_schema(&mut self, setup: Option<crate::schema::Setup>) {
        self.schema = setup;
    }

    /// Takes the schema server's set-up out of the table: a node hands it to its server, which
    /// owns it from then on (no copy of the innate schemas kept twice in RAM).
    #[cfg(feature = "schema")]
    pub fn take_schema(&mut self) -> Option<crate::schema::Setup> {
        self.schema.take()
    }

    /// The number of ports.
    pub fn port_count(&self) -> usize {
        self.ports.len()
    }

    /// The number of connections over all ports.
    pub fn connection_count(&self) -> usize {
        self.connections.len()
    }

    /// The number of decision nodes over all ports.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// All connections, port after port.
    pub fn connections(&self) -> &[Connection] {
        &self.connections
    }

    /// All decision nodes, port after port.
    pub fn nodes(&self) -> &[DecisionNode] {
        &self.nodes
    }

    /// The value ports' connection roots, value port after value port.
    pub fn roots(&self) -> &[NodeRef] {
        &self.roots
    }

    /// Port `index` with its slices, or `None`. Walks the ports before it (at most 16).
    pub fn port(&self, index: usize) -> Option<PortView<'_>> {
        self.ports().nth(index)
    }

    /// Who receives what port `index` delivers, or `None` for a port that does not exist. One
    /// load: unlike [`Table::port`], it walks nothing.
    pub fn consumer(&self, index: usize) -> Option<Consumer> {
        self.ports.get(index).map(|port| port.consumer)
    }

    /// The ports in order.
    pub fn ports(&self) -> impl Iterator<Item = PortView<'_>> {
        self.ranges()
            .filter_map(|(port, connections, nodes, roots)| {
                Some(PortView {
                    connections: self.connections.get(connections)?,
                    nodes: self.nodes.get(nodes)?,
                    root: port.root,
                    consumer: port.consumer,
                    value: port.value,
                    roots: self.roots.get(roots)?,
                })
            })
    }

    /// For each port, its record and its connections, decision nodes and value-port roots,
    /// taken in turn off the front of each list; `None` for a port whose lists run short (in a
    /// table that [`Table::validate`] refuses).
    pub(crate) fn parts(&self) -> impl Iterator<Item = Option<PortParts<'_>>> + '_ {
        let mut connections: &[Connection] = &self.connections;
        let mut nodes: &[DecisionNode] = &self.nodes;
        let mut roots: &[NodeRef] = &self.roots;
        self.ports.iter().map(move |port| {
            let root_count = if port.value.is_some() {
                port.connections
            } else {
                0
            };
            Some((
                *port,
                take(&mut connections, port.connections)?,
                take(&mut nodes, port.nodes)?,
                take(&mut roots, root_count)?,
            ))
        })
    }

    /// For each port, its record and the ranges of its connections, nodes and roots.
    fn ranges(&self) -> impl Iterator<Item = (Port, PortRange, PortRange, PortRange)> + '_ {
        let mut connections = 0usize;
        let mut nodes = 0usize;
        let mut roots = 0usize;
        self.ports.iter().map(move |port| {
            let connection_range =
                connections..connections.saturating_add(usize::from(port.connections));
            let node_range = nodes..nodes.saturating_add(usize::from(port.nodes));
            let root_count = if port.value.is_some() {
                usize::from(port.connections)
            } else {
                0
            };
            let root_range = roots..roots.saturating_add(root_count);
            connections = connection_range.end;
            nodes = node_range.end;
            roots = root_range.end;
            (*port, connection_range, node_range, root_range)
        })
    }
}

impl Port {
    /// The entry of the port's decision.
    pub const fn root(&self) -> NodeRef {
        self.root
    }

    /// Who receives what the port delivers.
    pub const fn consumer(&self) -> Consumer {
        self.consumer
    }

    /// What the port combines, for a value port.
    pub const fn value(&self) -> Option<ValueSpec> {
        self.value
    }
}

/// A range of indices into one of a table's lists.
type PortRange = Range<usize>;

/// A port's record and its part of the table's connections, decision nodes and value-port
/// roots ([`Table::parts`]).
pub(crate) type PortParts<'a> = (Port, &'a [Connection], &'a [DecisionNode], &'a [NodeRef]);

/// The first `count` items of `*items`, which keep the rest.
fn take<'a, T>(items: &mut &'a [T], count: impl Into<usize>) -> Option<&'a [T]> {
    let (part, rest) = items.split_at_checked(count.into())?;
    *items = rest;
    Some(part)
}

/// Checks the BLE groups' entries at port `port`, whose connections are `connections` (at most
/// 32, checked before): each claim is a connection of the port with
/// [`ble::CLAIM_SLOT_FILTER`], the claim of one group only, and not among the gated connections,
/// which are connections of the port.
fn check_claims<R: Verdict>(
    port: u8,
    connections: &[Connection],
    groups: &[Group],
) -> Result<(), R> {
    // Sets of connections in a u32, as `gated` is: with at most 32 connections, a claim beyond
    // bit 31 is beyond the port as well (no bit, so refused). 64-bit sets gave the same verdicts
    // in 28 bytes more of the NUCLEO-G474RE's flash with competitive dynamics, 88 without.
    let present = u32::try_from(connections.len())
        .ok()
        .and_then(|count| 1u32.checked_shl(count))
        .map_or(u32::MAX, |b| b.wrapping_sub(1));
    let mut claims = 0u32;
    for (index, group) in groups.iter().enumerate() {
        let error = |error| {
            R::refuse(|| TableError::Group {
                group: u8::try_from(index).unwrap_or(u8::MAX),
                error,
            })
        };
        for entry in group.ports.iter().filter(|entry| entry.port == port) {
            let claim = 1u32.checked_shl(u32::from(entry.claim)).unwrap_or(0);
            let gated = entry.gated;
            if claim & present == 0 || gated & !present != 0 || gated & claim != 0 {
                return Err(error(GroupError::Connection { port }));
            }
            let filter = connections.get(usize::from(entry.claim)).map(|c| c.filter);
            if filter != Some(ble::CLAIM_SLOT_FILTER) {
                return Err(R::refuse(|| TableError::ClaimFilter {
                    port,
                    connection: entry.claim,
                }));
            }
            if claims & claim != 0 {
                return Err(error(GroupError::SharedClaim { port }));
            }
            claims |= claim;
        }
    }
    Ok(())
}

/// The filter of connection `connection` of port `port`, `None` beyond the port or the table:
/// what `Table::port(port)` shows once the counts are checked ([`Table::validate`] asks only
/// then), without walking every port's ranges. One copy for every table type: not generic, and
/// left to the inliner (a board has one table type: inlined into its one caller, 36 bytes of the
/// NUCLEO-G474RE's flash less than out of line).
#[cfg(feature = "dynamics")]
fn connection_filter(
    ports: &[Port],
    connections: &[Connection],
    port: u8,
    connection: u8,
) -> Option<Filter> {
    let port = usize::from(port);
    if connection >= ports.get(port)?.connections {
        return None;
    }
    // At most 255 connections per port and MAX_PORTS ports: the sums cannot overflow a usize,
    // and plain additions spare the saturations.
    let first = ports.get(..port)?.iter().fold(0usize, |sum, p| {
        sum.wrapping_add(usize::from(p.connections))
    });
    connections
        .get(first.wrapping_add(usize::from(connection)))
        .map(|c| c.filter)
}

fn validate_port<R: Verdict>(
    index: u8,
    port: &Port,
    connections: &[Connection],
    nodes: &[DecisionNode],
    roots: &[NodeRef],
) -> Result<(), R> {
    for (position, connection) in connections.iter().enumerate() {
        let position = u8::try_from(position)
            .map_err(|_| R::refuse(|| TableError::PortTooWide { port: index }))?;
        connection.stimulation.validate().map_err(|error| {
            R::refuse(|| TableError::Parameter {
                port: index,
                connection: position,
                error,
            })
        })?;
        connection.filter.validate().map_err(|error| {
            R::refuse(|| TableError::Filter {
                port: index,
                connection: position,
                error,
            })
        })?;
    }
    port.consumer
        .validate()
        .map_err(|error| R::refuse(|| TableError::Consumer { port: index, error }))?;
    decision::validate(nodes, port.root, port.connections)
        .map_err(|error| R::refuse(|| TableError::Decision { port: index, error }))?;
    let Some(spec) = port.value else {
        return if roots.is_empty() {
            Ok(())
        } else {
            Err(R::refuse(|| TableError::RootCountMismatch))
        };
    };
    let value_error = |error| R::refuse(|| TableError::Value { port: index, error });
    spec.validate().map_err(value_error)?;
    if port.root != NodeRef::NOBODY {
        return Err(value_error(ValueError::PortRoot));
    }
    if roots.len() != usize::from(port.connections) {
        return Err(R::refuse(|| TableError::RootCountMismatch));
    }
    for (connection, &root) in roots.iter().enumerate() {
        if !decision::root_ok(nodes, root, port.connections) {
            return Err(value_error(ValueError::BadRoot {
                connection: u8::try_from(connection).unwrap_or(u8::MAX),
            }));
        }
    }
    Ok(())
}

crate::wire::decode_struct!(Connection {
    filter,
    stimulation
});

impl crate::wire::Decode for Port {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        Port {
            connections: r.decode(),
            nodes: r.decode(),
            root: r.decode(),
            consumer: r.decode(),
            value: r.option(),
        }
    }
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize> crate::wire::Decode
    for Table<PORTS, CONNECTIONS, NODES>
{
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        let mut table = Table::new();
        table.decode_sized(r);
        table
    }
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Table<PORTS, CONNECTIONS, NODES>
{
    /// The table's decode into `self`, an empty table ([`Table::new`]), with what its body
    /// holds: `(sizes, value-port roots)`, the lengths read, including elements beyond the
    /// capacities ([`crate::wire::Reader::fill_within`]: a list longer than its room is an error
    /// that leaves the rest of the body read, so that the loader tells
    /// [`crate::image::LoadError::ExceedsCapacity`] from the sizes).
    // Out of line: inlined into the loader, each list's decode reached the table at large
    // offsets of the loader's frame; here the table is near. 156 bytes less of the
    // NUCLEO-G474RE's flash with competitive dynamics, 80 without. Run once per image.
    #[inline(never)]
    pub(crate) fn decode_sized(
        &mut self,
        r: &mut crate::wire::Reader<'_>,
    ) -> (crate::image::TableSize, usize) {
        // Each list is decoded into its field of the caller's table, not built apart and moved
        // in: a move per field was code, on the boards with the arbiter built in place too
        // (`Arbiter::new`) 72 bytes of flash with competitive dynamics, 48 without; a table
        // built here and returned was moved too (and reached at large offsets of this frame),
        // 152 bytes with the schema server, 56 without.
        let size = crate::image::TableSize {
            ports: r.fill_within(&mut self.ports),
            connections: r.fill_within(&mut self.connections),
            nodes: r.fill_within(&mut self.nodes),
        };
        let roots = r.fill_within(&mut self.roots);
        // Without BLE the list must be empty: a table with groups is refused, its body unreadable
        // here (a node needs the feature to run it), as with dynamics and filters below.
        #[cfg(feature = "ble")]
        r.fill_within(&mut self.groups);
        #[cfg(not(feature = "ble"))]
        r.empty::<u8, 0>();
        #[cfg(feature = "dynamics")]
        {
            r.fill_within(&mut self.dynamics);
            r.fill_within(&mut self.gate_sources);
            r.fill_within(&mut self.gate_links);
        }
        // Without competitive dynamics the three lists must be empty: a table that has them
        // is refused, its body unreadable here (a node needs the feature to run it).
        #[cfg(not(feature = "dynamics"))]
        for _ in 0..3 {
            r.empty::<u8, 0>();
        }
        // Format 6: after the dynamics part, the HBBA message filters.
        #[cfg(feature = "filters")]
        {
            r.fill(&mut self.filters.connections);
            r.fill(&mut self.filters.profiles);
        }
        #[cfg(not(feature = "filters"))]
        for _ in 0..2 {
            r.empty::<u8, 0>();
        }
        // Format 7: the schema server. Without the feature it must be absent: a node needs the
        // feature to run it.
        #[cfg(feature = "schema")]
        {
            self.schema = r.option();
        }
        #[cfg(not(feature = "schema"))]
        r.none();
        (size, roots)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::level::Gain;

    fn connection(id: u32) -> Connection {
        Connection {
            filter: Filter::exact(id, false).unwrap(),
            stimulation: Stimulation::new(Gain::ONE, 1_000_000, 0).unwrap(),
        }
    }

    #[test]
    fn ports_own_consecutive_ranges() {
        let mut table: Table = Table::new();
        let deliver0 = NodeRef::deliver(0).unwrap();
        table
            .push_port(&[connection(1), connection(2)], &[], deliver0)
            .unwrap();
        table
            .push_port(&[connection(3)], &[], NodeRef::NOBODY)
            .unwrap();
        table.validate().unwrap();
        let ports: std::vec::Vec<_> = table.ports().collect();
        assert_eq!(ports.len(), 2);
        assert_eq!(ports[0].connections, &[connection(1), connection(2)]);
        assert_eq!(ports[1].connections, &[connection(3)]);
        assert_eq!(table.port(1).map(|p| p.root), Some(NodeRef::NOBODY));
        assert!(table.port(2).is_none());
    }

    #[test]
    fn bad_ports_leave_the_table_unchanged() {
        let mut table: Table = Table::new();
        let bad_root = NodeRef::deliver(3).unwrap();
        assert_eq!(
            table.push_port(&[connection(1)], &[], bad_root),
            Err(TableError::Decision {
                port: 0,
                error: DecisionError::BadRoot
            })
        );
        assert_eq!(table, Table::new());
        let too_wide: std::vec::Vec<_> = (0..33).map(connection).collect();
        assert_eq!(
            table.push_port(&too_wide, &[], NodeRef::NOBODY),
            Err(TableError::PortTooWide { port: 0 })
        );
        for _ in 0..MAX_PORTS {
            table.push_port(&[], &[], NodeRef::NOBODY).unwrap();
        }
        assert_eq!(
            table.push_port(&[], &[], NodeRef::NOBODY),
            Err(TableError::TooManyPorts)
        );
    }

    #[test]
    fn full_capacity_is_expressible() {
        // 16 ports of 32 connections each.
        let mut table: Table = Table::new();
        for port in 0..MAX_PORTS as u32 {
            let connections: std::vec::Vec<_> =
                (0..32).map(|k| connection(port * 32 + k)).collect();
            table.push_port(&connections, &[], NodeRef::NOBODY).unwrap();
        }
        table.validate().unwrap();
        assert_eq!(table.connection_count(), 512);
    }

    #[test]
    fn consumers_are_set_per_port_and_checked() {
        let mut table: Table = Table::new();
        table
            .push_port(&[connection(1)], &[], NodeRef::NOBODY)
            .unwrap();
        table
            .push_port(&[connection(2)], &[], NodeRef::NOBODY)
            .unwrap();
        assert_eq!(table.port(0).map(|p| p.consumer), Some(Consumer::Local));
        let out = Consumer::Republish(crate::OutputId::new(0x300, false).unwrap());
        table.set_consumer(1, out).unwrap();
        assert_eq!(table.port(0).map(|p| p.consumer), Some(Consumer::Local));
        assert_eq!(table.port(1).map(|p| p.consumer), Some(out));
        table.validate().unwrap();
        let before = table.clone();
        assert_eq!(
            table.set_consumer(2, out),
            Err(TableError::NoSuchPort { port: 2 })
        );
        assert_eq!(table, before);
    }

    #[test]
    fn small_capacities_are_enforced_by_push_port() {
        let mut table: Table<2, 3, 1> = Table::new();
        assert_eq!(Table::<2, 3, 1>::CAPACITY, (2, 3, 1));
        table
            .push_port(&[connection(1), connection(2)], &[], NodeRef::NOBODY)
            .unwrap();
        assert_eq!(
            table.push_port(&[connection(3), connection(4)], &[], NodeRef::NOBODY),
            Err(TableError::TooManyConnections)
        );
        let node = DecisionNode {
            var: 0,
            low: NodeRef::NOBODY,
            high: NodeRef::deliver(0).unwrap(),
        };
        assert_eq!(
            table.push_port(&[connection(3)], &[node, node], NodeRef::node(0).unwrap()),
            Err(TableError::TooManyNodes)
        );
        table
            .push_port(&[connection(3)], &[node], NodeRef::node(0).unwrap())
            .unwrap();
        assert_eq!(
            table.push_port(&[], &[], NodeRef::NOBODY),
            Err(TableError::TooManyPorts)
        );
        table.validate().unwrap();
        assert_eq!(table.connection_count(), 3);
    }
}
