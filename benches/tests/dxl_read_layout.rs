//! The 41-DOF Hubo reading Hardware Error Status, Present Current, Present Velocity and Present
//! Position every cycle: the bytes the Dynamixel 2.0 stage puts on the wire with the layout
//! the device chooses equal the DynamixelSDK minimum for the same registers (exact numbers),
//! and indirect addressing takes strictly fewer bytes than the contiguous span. Counted by the
//! bus simulator, not timed. The `devices` bench prints the same figures.

#[path = "../benches/support/dxl_reads.rs"]
mod dxl_reads;

use conductor_devices::device::Layout;
use conductor_devices::protocol_stage::Dxl2ReadMode;
use conductor_protocols::dynamixel2 as dxl;
use dxl_reads::{measure, sdk_minimum, sdk_reads, Reading, Setup, REGISTERS};

const BAUD: u32 = 1_000_000;
const CYCLES: u64 = 10;

/// The device's choice, the contiguous span, and the SDK minimum, 41 servos on one bus. The
/// servos are set up directly (the indirect addresses written through the stage; see
/// `direct_setup_reads_what_bring_up_reads`).
/// FAST SYNC READ of 11 B: (14 + 41) + (8 + 41·(4 + 11)) = 55 + 623 = 678 B.
/// SYNC READ of 11 B: 55 + 41·(11 + 11) = 55 + 902 = 957 B.
/// The span (70..136, 66 B): SYNC 55 + 41·77 = 3212 B. As FAST SYNC READ its combined reply
/// would be 8 + 41·70 = 2878 B, more than the 1 KiB packet buffer of the stage (and of the
/// DynamixelSDK, whose GroupFastSyncRead would send 2933 B and receive nothing), so the stage
/// reads the span with SYNC READ in both modes.
#[test]
fn hubo_reads_at_the_sdk_minimum_and_indirect_beats_the_span() {
    for (mode, fast, chosen, span) in [
        (Dxl2ReadMode::Fast, true, 678, 3212),
        (Dxl2ReadMode::Sync, false, 957, 3212),
    ] {
        let ours = measure(41, mode, Reading::Chosen, Setup::Direct, BAUD, CYCLES);
        assert!(
            ours.complete(41),
            "{mode:?}: every value delivered: {ours:?}"
        );
        assert_eq!(
            ours.layout,
            Layout {
                indirect: 11,
                contiguous: 66
            },
            "{mode:?}: the device chose indirect addressing"
        );
        assert_eq!(ours.read_bytes, chosen, "{mode:?}: bytes per cycle");
        let sdk = sdk_minimum(41, &REGISTERS, fast);
        assert_eq!(sdk.bytes, chosen, "{mode:?}: SDK minimum {}", sdk.name);
        assert!(sdk.indirect, "{}", sdk.name);
        // The goal SYNC WRITE beside it: 14 + 41·(1 + 4) (no stuffing at these goals).
        assert_eq!(ours.write_bytes, 219);

        let contiguous = measure(41, mode, Reading::Contiguous, Setup::Direct, BAUD, CYCLES);
        assert_eq!(
            contiguous.layout,
            Layout {
                indirect: 0,
                contiguous: 0
            },
            "configure_reads not called: no layout chosen"
        );
        assert!(
            contiguous.complete(41),
            "{mode:?}: every value of the span delivered: {contiguous:?}"
        );
        assert_eq!(contiguous.read_bytes, span, "{mode:?}: the span");
        assert!(ours.read_bytes < contiguous.read_bytes);
        // The SDK reading the same span: GroupSyncRead sends the same bytes as the stage; its
        // GroupFastSyncRead would send fewer but expects a reply its own buffer cannot hold.
        let sdk_span = |class: &str| {
            let name = format!("{class}(70, 66), the span");
            sdk_reads(41, &REGISTERS)
                .into_iter()
                .find(|r| r.name == name)
                .expect("the span read")
                .bytes
        };
        assert_eq!(sdk_span("GroupSyncRead"), span);
        assert_eq!(sdk_span("GroupFastSyncRead"), 2933);
    }
}

/// The same on the busiest bus of the 2- and 4-bus splits (21 and 11 servos).
#[test]
fn bus_splits_read_at_the_sdk_minimum() {
    for n in [21u8, 11] {
        for (mode, fast) in [(Dxl2ReadMode::Fast, true), (Dxl2ReadMode::Sync, false)] {
            let ours = measure(n, mode, Reading::Chosen, Setup::Direct, BAUD, CYCLES);
            assert!(ours.complete(n), "{n} servos, {mode:?}: {ours:?}");
            let sdk = sdk_minimum(n, &REGISTERS, fast);
            assert_eq!(ours.read_bytes, sdk.bytes, "{n} servos, {mode:?}");
            let span = measure(n, mode, Reading::Contiguous, Setup::Direct, BAUD, CYCLES);
            assert!(ours.read_bytes < span.read_bytes, "{n} servos, {mode:?}");
        }
    }
}

/// The shortcut the measurements take reads exactly what the devices' own bring-up sets up:
/// 41 servos, both read modes (bring-up's long reads go out as SYNC READ when a combined FAST
/// reply would not fit one packet), both layouts, the same bytes per cycle and every value.
#[test]
fn direct_setup_reads_what_bring_up_reads() {
    for mode in [Dxl2ReadMode::Sync, Dxl2ReadMode::Fast] {
        for reading in [Reading::Chosen, Reading::Contiguous] {
            let managed = measure(41, mode, reading, Setup::BringUp, BAUD, CYCLES);
            let direct = measure(41, mode, reading, Setup::Direct, BAUD, CYCLES);
            assert!(
                managed.complete(41) && direct.complete(41),
                "{mode:?} {reading:?}"
            );
            assert_eq!(managed.layout, direct.layout);
            assert_eq!(
                managed.read_bytes, direct.read_bytes,
                "{mode:?} {reading:?}"
            );
            assert_eq!(
                managed.write_bytes, direct.write_bytes,
                "{mode:?} {reading:?}"
            );
        }
    }
}

/// The SDK figures are computed from the packet layouts; the encoders of
/// `conductor_protocols` build packets of those lengths.
#[test]
fn sdk_packet_lengths_match_the_encoders() {
    let mut buf = vec![0u8; 8192];
    let ids: Vec<u8> = (1..=41).collect();
    let data = [0u8; 11];
    let inst = dxl::fast_sync_read(&mut buf, 224, 11, &ids).unwrap();
    assert_eq!(inst, dxl::sync_read(&mut buf, 224, 11, &ids).unwrap());
    assert_eq!(inst, 14 + 41);
    let status = dxl::status(&mut buf, 1, 0, &data).unwrap();
    assert_eq!(status, 11 + 11);
    let slices: Vec<_> = ids
        .iter()
        .map(|&id| dxl::FastStatusSlice {
            error: 0,
            id,
            data: &data,
        })
        .collect();
    let fast = dxl::fast_status(&mut buf, &slices).unwrap();
    assert_eq!(fast, 8 + 41 * (4 + 11));
    let entries = ids.iter().map(|&id| dxl::BulkReadEntry {
        id,
        addr: 70,
        len: 66,
    });
    assert_eq!(dxl::bulk_read(&mut buf, entries).unwrap(), 10 + 5 * 41);
    // The minimum over every SDK way is the indirect FAST SYNC READ; without FAST SYNC READ,
    // the indirect SYNC READ.
    assert_eq!(
        inst + fast,
        sdk_minimum(41, &REGISTERS, true).bytes as usize
    );
    assert_eq!(
        inst + 41 * status,
        sdk_minimum(41, &REGISTERS, false).bytes as usize
    );
}
