//! The pab protocol's services as DBC signals, from the core's layouts
//! (`pab_core::protocol::layout`, the one description of every payload): each field a signal,
//! the value tables of its enumerations, and a comment per service.

use pab_core::protocol::Service;
use pab_core::protocol::layout::{Field, Framing, Scale, Values, layout};

use super::{DbcSignal, Q31_FACTOR, signal, with_unit, with_values};

/// The signals of a service's payload, from its layout in the core
/// (`pab_core::protocol::layout`); `None` for table and schema transfer (ISO-TP segments, not a
/// fixed layout).
pub fn service_signals(service: Service) -> Option<Vec<DbcSignal>> {
    let layout = layout(service);
    if layout.framing == Framing::IsoTp {
        return None;
    }
    Some(layout.fields.iter().map(field_signal).collect())
}

/// A field as a DBC signal: little endian, its scale, its maximum (the named values' largest,
/// the layout's maximum, or the width's), its unit and value table.
fn field_signal(field: &Field) -> DbcSignal {
    let mut signal = with_unit(
        signal(
            field.name,
            u32::from(field.bit),
            u32::from(field.bits),
            field.doc,
        ),
        field.unit,
    );
    signal.signed = field.signed;
    if field.scale == Scale::Q31 {
        signal.factor = Q31_FACTOR.to_string();
    }
    if let Some(max) = field.max {
        signal.max = max.to_string();
    }
    if field.values != Values::None {
        signal = with_values(signal, field.values.iter().collect());
    }
    signal
}

/// The comment of a service's messages: its name, code, priority, and the layout's summary.
pub(super) fn service_comment(service: Service) -> String {
    let layout = layout(service);
    let empty = if layout.len == 0 && layout.framing == Framing::Fixed {
        ", no payload"
    } else {
        ""
    };
    format!(
        "{service:?} (service 0x{:02X}, priority {}{empty}): {}",
        service.code(),
        service.priority().value(),
        layout.summary
    )
}
