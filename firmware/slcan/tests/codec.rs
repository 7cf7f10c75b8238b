//! The SLCAN codec and adapter, byte by byte: every standard identifier and length through
//! format and parse, the exact lines the kernel's slcan driver writes and reads, every kind of
//! malformed line, the adapter's answers, and random bytes (proptest).

use embedded_can::{ExtendedId, Frame as _, Id, StandardId};
use pab_slcan::{
    BEL, Bitrate, CR, Command, Device, Frame, Line, LineError, LineReader, MAX_LINE, ParseError,
    STATUS_DATA_OVERRUN, format_frame, parse,
};
use proptest::prelude::*;

fn std_id(raw: u16) -> Id {
    Id::Standard(StandardId::new(raw).unwrap())
}

fn ext_id(raw: u32) -> Id {
    Id::Extended(ExtendedId::new(raw).unwrap())
}

fn data(id: Id, bytes: &[u8]) -> Frame {
    Frame::data(id, bytes).unwrap()
}

fn remote(id: Id, dlc: usize) -> Frame {
    Frame::new_remote(id, dlc).unwrap()
}

/// Parses `line` given with its CR, through a fresh reader, as the board does.
fn read_line(line: &[u8]) -> Vec<Result<Command, LineError>> {
    let mut reader = LineReader::new();
    line.iter().filter_map(|&b| reader.push(b)).collect()
}

fn round_trip(frame: &Frame) {
    let line = format_frame(frame).unwrap();
    let bytes = line.as_bytes();
    assert!(bytes.len() <= MAX_LINE);
    assert_eq!(bytes.last(), Some(&CR));
    assert_eq!(
        parse(&bytes[..bytes.len() - 1]),
        Ok(Command::Frame(*frame)),
        "{line:?}"
    );
    assert_eq!(read_line(bytes), vec![Ok(Command::Frame(*frame))]);
}

#[test]
fn every_standard_identifier_and_length_round_trips() {
    for raw in 0..=0x7FF_u16 {
        for len in 0..=8 {
            let payload: Vec<u8> = (0..len).map(|i| (raw as u8).wrapping_mul(31) ^ i).collect();
            round_trip(&data(std_id(raw), &payload));
            round_trip(&remote(std_id(raw), usize::from(len)));
        }
    }
}

#[test]
fn every_byte_value_in_every_position_round_trips() {
    for value in 0..=255u8 {
        for position in 0..8 {
            let mut payload = [0x5A; 8];
            payload[position] = value;
            round_trip(&data(std_id(0x123), &payload));
            round_trip(&data(ext_id(0x1ABC_DEF0), &payload[..=position]));
        }
    }
}

#[test]
fn extended_identifiers_at_the_edges_round_trip() {
    for raw in [
        0,
        1,
        0x7FF,
        0x800,
        0xFFFF,
        0x10000,
        0x0ABC_DEF0,
        0x1FFF_FFFE,
        0x1FFF_FFFF,
    ] {
        for len in 0..=8u8 {
            round_trip(&data(ext_id(raw), &vec![0xA5; usize::from(len)]));
            round_trip(&remote(ext_id(raw), usize::from(len)));
        }
    }
}

#[test]
fn lines_are_the_ones_the_kernel_driver_writes() {
    // Linux's slcan: "%c%03X" / "%c%08X", the DLC as one digit, data as "%02X", then CR.
    let cases: [(Frame, &[u8]); 6] = [
        (data(std_id(0x123), &[0xDE, 0xAD]), b"t1232DEAD\r"),
        (data(std_id(0x7FF), &[]), b"t7FF0\r"),
        (
            data(ext_id(0x18DA_F101), &[1, 2, 3, 4, 5, 6, 7, 8]),
            b"T18DAF10180102030405060708\r",
        ),
        (data(ext_id(0), &[0xFF]), b"T000000001FF\r"),
        (remote(std_id(0x001), 4), b"r0014\r"),
        (remote(ext_id(0x1FFF_FFFF), 8), b"R1FFFFFFF8\r"),
    ];
    for (frame, line) in cases {
        assert_eq!(format_frame(&frame).unwrap().as_bytes(), line);
        assert_eq!(read_line(line), vec![Ok(Command::Frame(frame))]);
    }
    // The longest line there is.
    assert_eq!(
        format_frame(&cases[2].0).unwrap().as_bytes().len(),
        MAX_LINE
    );
}

#[test]
fn lower_case_hex_is_accepted() {
    assert_eq!(
        parse(b"t7ff2abcd"),
        Ok(Command::Frame(data(std_id(0x7FF), &[0xAB, 0xCD])))
    );
    assert_eq!(
        parse(b"T1fffffff1e0"),
        Ok(Command::Frame(data(ext_id(0x1FFF_FFFF), &[0xE0])))
    );
}

#[test]
fn malformed_frames_say_what_is_wrong() {
    let cases: [(&[u8], ParseError); 22] = [
        (b"t", ParseError::Length),
        (b"t12", ParseError::Length),
        (b"t123", ParseError::Length),
        (b"t1231", ParseError::Length), // one data byte announced, none given
        (b"t1231A", ParseError::Length), // half a byte
        (b"t1231AB0", ParseError::Length), // more than announced
        (b"t1239", ParseError::Dlc),    // CAN FD lengths are not classic CAN
        (b"t123F", ParseError::Dlc),
        (b"t123x", ParseError::Dlc),
        (b"t800F", ParseError::Dlc), // the DLC is checked before the range
        (b"t8000", ParseError::Identifier), // 11 bits at most
        (b"tFFF0", ParseError::Identifier),
        (b"T200000000", ParseError::Identifier), // 29 bits at most
        (b"TFFFFFFFF0", ParseError::Identifier),
        (b"t12G0", ParseError::Hex),
        (b"t1231ZZ", ParseError::Hex),
        (b"t 120", ParseError::Hex),
        (b"T1234567", ParseError::Length),
        (b"r12391", ParseError::Dlc),
        (b"r12311", ParseError::Length), // a remote frame carries no data
        (b"R1234567801", ParseError::Length),
        (b"r1G31", ParseError::Hex),
    ];
    for (line, error) in cases {
        assert_eq!(parse(line), Err(error), "{}", String::from_utf8_lossy(line));
        let mut with_cr = line.to_vec();
        with_cr.push(CR);
        assert_eq!(read_line(&with_cr), vec![Err(LineError::Malformed(error))]);
    }
}

#[test]
fn commands_parse_with_their_arguments() {
    assert_eq!(parse(b"O"), Ok(Command::Open));
    assert_eq!(parse(b"L"), Ok(Command::ListenOnly));
    assert_eq!(parse(b"C"), Ok(Command::Close));
    assert_eq!(parse(b"V"), Ok(Command::Version));
    assert_eq!(parse(b"v"), Ok(Command::FirmwareVersion));
    assert_eq!(parse(b"N"), Ok(Command::SerialNumber));
    assert_eq!(parse(b"F"), Ok(Command::Status));
    let rates = [
        10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
    ];
    for (digit, rate) in (b'0'..=b'8').zip(rates) {
        let Ok(Command::Bitrate(bitrate)) = parse(&[b'S', digit]) else {
            panic!("S{}", digit as char)
        };
        assert_eq!(bitrate.bits_per_second(), rate);
        assert_eq!(Bitrate::from_digit(digit), Some(bitrate));
    }
    assert_eq!(parse(b"S9"), Err(ParseError::Argument));
    assert_eq!(parse(b"S"), Err(ParseError::Length));
    assert_eq!(parse(b"S66"), Err(ParseError::Length));
    assert_eq!(
        parse(b"s031C"),
        Ok(Command::BitTiming {
            btr0: 0x03,
            btr1: 0x1C
        })
    );
    assert_eq!(parse(b"s031"), Err(ParseError::Length));
    assert_eq!(parse(b"s03G1"), Err(ParseError::Hex));
    assert_eq!(parse(b"Z0"), Ok(Command::Timestamps(false)));
    assert_eq!(parse(b"Z1"), Ok(Command::Timestamps(true)));
    assert_eq!(parse(b"Z2"), Err(ParseError::Argument));
    assert_eq!(parse(b"Z"), Err(ParseError::Length));
    for bare in [b'O', b'L', b'C', b'V', b'v', b'N', b'F'] {
        assert_eq!(parse(&[bare, b'1']), Err(ParseError::Length));
    }
    for letter in [b'M', b'm', b'X', b'W', b'Q', b'U', b'P', b'A', b'E', b'l'] {
        assert_eq!(parse(&[letter, b'0']), Ok(Command::Unsupported(letter)));
    }
    assert_eq!(parse(b"?"), Err(ParseError::UnknownCommand(b'?')));
    assert_eq!(parse(&[0xFF, b'1']), Err(ParseError::UnknownCommand(0xFF)));
    assert_eq!(parse(b""), Err(ParseError::Length));
}

#[test]
fn every_line_of_one_or_two_bytes_parses_or_fails_without_panicking() {
    for a in 0..=255u8 {
        let _ = parse(&[a]);
        for b in 0..=255u8 {
            let _ = parse(&[a, b]);
        }
    }
}

#[test]
fn a_line_too_long_is_dropped_whole_and_the_next_one_is_read() {
    let mut reader = LineReader::new();
    let mut seen = Vec::new();
    let long = [b'0'; 100];
    for &b in b"t1230"
        .iter()
        .chain(long.iter())
        .chain(b"\rt1231AB\r".iter())
    {
        if let Some(result) = reader.push(b) {
            seen.push(result);
        }
    }
    assert_eq!(
        seen,
        vec![
            Err(LineError::TooLong),
            Ok(Command::Frame(data(std_id(0x123), &[0xAB])))
        ]
    );
    // MAX_LINE - 1 characters fit; one more does not.
    let longest = format_frame(&data(ext_id(0x1FFF_FFFF), &[0; 8])).unwrap();
    assert_eq!(read_line(longest.as_bytes()).len(), 1);
    assert!(read_line(longest.as_bytes())[0].is_ok());
    let mut one_more = longest.as_bytes()[..MAX_LINE - 1].to_vec();
    one_more.extend_from_slice(b"0\r");
    assert_eq!(read_line(&one_more), vec![Err(LineError::TooLong)]);
}

#[test]
fn empty_lines_and_line_feeds_are_ignored() {
    let mut reader = LineReader::new();
    let results: Vec<_> = b"\r\r\n\nO\r\nC\n"
        .iter()
        .filter_map(|&b| reader.push(b))
        .collect();
    assert_eq!(results, vec![Ok(Command::Open), Ok(Command::Close)]);
    assert!(!reader.pending());
    reader.push(b't');
    assert!(reader.pending());
}

fn answer(device: &mut Device, line: &[u8]) -> (Option<Frame>, Vec<u8>, Option<LineError>) {
    let mut reader = LineReader::new();
    let mut frame = None;
    let mut reply = Vec::new();
    let mut error = None;
    for &b in line {
        if let Some(result) = reader.push(b) {
            let outcome = device.handle(result);
            frame = frame.or(outcome.frame);
            reply.extend_from_slice(outcome.reply.as_bytes());
            error = error.or(outcome.error);
        }
    }
    (frame, reply, error)
}

#[test]
fn the_device_answers_slcand_and_passes_frames_while_open() {
    let mut device = Device::new(*b"0001");
    assert!(device.is_open(), "a node's channel is open from boot");
    // What `slcand -o -c -s6` writes before attaching the line discipline.
    assert_eq!(
        answer(&mut device, b"C\rS6\rO\r"),
        (None, b"\r\r\r".to_vec(), None)
    );
    assert_eq!(device.bitrate(), Some(Bitrate::K500));
    assert!(device.is_open());
    let frame = data(std_id(0x120), &[1, 2]);
    assert_eq!(
        answer(&mut device, b"t12020102\r"),
        (Some(frame), b"z\r".to_vec(), None)
    );
    let frame = data(ext_id(0x10), &[]);
    assert_eq!(
        answer(&mut device, b"T000000100\r"),
        (Some(frame), b"Z\r".to_vec(), None)
    );
    let frame = remote(std_id(0x7FF), 3);
    assert_eq!(
        answer(&mut device, b"r7FF3\r"),
        (Some(frame), b"z\r".to_vec(), None)
    );
    // Settings only while closed; a second O is refused.
    assert_eq!(answer(&mut device, b"S4\r").1, [BEL]);
    assert_eq!(answer(&mut device, b"s031C\r").1, [BEL]);
    assert_eq!(answer(&mut device, b"O\r").1, [BEL]);
    assert_eq!(device.bitrate(), Some(Bitrate::K500));
    // Closed: frames are refused and not passed on; settings are taken.
    assert_eq!(answer(&mut device, b"C\r").1, [CR]);
    assert_eq!(answer(&mut device, b"t1230\r"), (None, vec![BEL], None));
    assert_eq!(answer(&mut device, b"F\r").1, [BEL]);
    assert_eq!(answer(&mut device, b"s031C\r").1, [CR]);
    assert_eq!(device.bit_timing(), Some((0x03, 0x1C)));
    assert_eq!(answer(&mut device, b"Z0\r").1, [CR]);
    assert_eq!(answer(&mut device, b"Z1\r").1, [BEL]);
    assert_eq!(answer(&mut device, b"C\r").1, [CR]);
    assert_eq!(answer(&mut device, b"O\r").1, [CR]);
    // Identification, in an adapter's format.
    assert_eq!(answer(&mut device, b"V\r").1, b"V0100\r");
    assert_eq!(answer(&mut device, b"v\r").1, b"v0100\r");
    assert_eq!(answer(&mut device, b"N\r").1, b"N0001\r");
    // Not implemented: refused, not an error of the line.
    for line in [&b"L\r"[..], b"M00000000\r", b"m00000000\r", b"X1\r", b"l\r"] {
        assert_eq!(answer(&mut device, line), (None, vec![BEL], None));
    }
    assert!(device.is_open());
}

#[test]
fn malformed_lines_are_refused_and_reported() {
    let mut device = Device::new(*b"0001");
    let (frame, reply, error) = answer(&mut device, b"t12G0\r");
    assert_eq!((frame, reply), (None, vec![BEL]));
    assert_eq!(error, Some(LineError::Malformed(ParseError::Hex)));
    let (_, _, error) = answer(&mut device, b"hello\r");
    assert_eq!(
        error,
        Some(LineError::Malformed(ParseError::UnknownCommand(b'h')))
    );
    let (_, _, error) = answer(&mut device, &[b'x'; 40]);
    assert_eq!(error, None, "no line end yet");
}

#[test]
fn status_reports_an_overrun_once() {
    let mut device = Device::new(*b"0001");
    assert_eq!(answer(&mut device, b"F\r").1, b"F00\r");
    device.note_overrun();
    assert_eq!(
        answer(&mut device, b"F\r").1,
        format!("F{STATUS_DATA_OVERRUN:02X}\r").as_bytes()
    );
    assert_eq!(answer(&mut device, b"F\r").1, b"F00\r");
}

#[test]
fn replies_show_readably_in_debug_output() {
    assert_eq!(format!("{:?}", Line::refused()), "Line(\"\\x07\")");
    assert_eq!(
        format!("{:?}", format_frame(&data(std_id(1), &[])).unwrap()),
        "Line(\"t0010\\r\")"
    );
}

fn any_frame() -> impl Strategy<Value = Frame> {
    let id = prop_oneof![
        (0..=0x7FF_u16).prop_map(std_id),
        (0..=0x1FFF_FFFF_u32).prop_map(ext_id),
    ];
    (
        id,
        proptest::collection::vec(any::<u8>(), 0..=8),
        any::<bool>(),
        0..=8usize,
    )
        .prop_map(|(id, payload, is_remote, dlc)| {
            if is_remote {
                remote(id, dlc)
            } else {
                data(id, &payload)
            }
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    #[test]
    fn any_frame_round_trips(frame in any_frame()) {
        round_trip(&frame);
    }

    /// Random bytes never panic, and a CR followed by a good line always gets that line through:
    /// garbage never desynchronises the reader for longer than up to the next CR.
    #[test]
    fn random_bytes_never_panic_and_the_next_line_gets_through(
        noise in proptest::collection::vec(any::<u8>(), 0..200),
        frame in any_frame(),
    ) {
        let mut reader = LineReader::new();
        let mut device = Device::new(*b"0001");
        for &b in &noise {
            if let Some(result) = reader.push(b) {
                let outcome = device.handle(result);
                prop_assert!(outcome.reply.as_bytes().len() <= MAX_LINE);
                if let Some(frame) = outcome.frame {
                    // Whatever got through is a frame its own line would have produced.
                    let line = format_frame(&frame).unwrap();
                    prop_assert_eq!(parse(&line.as_bytes()[..line.as_bytes().len() - 1]),
                        Ok(Command::Frame(frame)));
                }
            }
        }
        // Make sure the channel is open, then a clean line.
        let mut tail = b"\rO\r".to_vec();
        tail.extend_from_slice(format_frame(&frame).unwrap().as_bytes());
        let mut got = None;
        for &b in &tail {
            if let Some(result) = reader.push(b) {
                got = device.handle(result).frame.or(got);
            }
        }
        prop_assert_eq!(got, Some(frame));
    }

    /// Printable noise (what a confused host would send) parses or fails, never panics.
    #[test]
    fn printable_lines_parse_or_fail(line in "[tTrRsSZOCFVvN0-9A-Fa-fxX ]{0,30}") {
        let _ = parse(line.as_bytes());
    }
}
