//! The owner's per-tick path (publish samples, notify the tick, drain command frames) performs
//! no heap allocation once set up. Checked with a counting global allocator that counts only
//! this thread's allocations while measuring.

use conductor_bus::{
    monotonic_ns, Bus, CommandReceiver, Controller, Domain, StateMeta, StatePublisher, StateSpec,
    StateSubscriber,
};
use conductor_testkit::alloc::{measure, Counting};

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn publishing_and_draining_allocate_nothing() {
    // The counter works (a test that cannot fail proves nothing).
    let (_, n) = measure(|| vec![1u8; 16]);
    assert_eq!(n, 1);

    let d = Domain::unique("noalloc").unwrap();
    let bus = Bus::open(&d, "owner").unwrap();
    let specs = StateSpec::numbered(
        ["a", "b", "c"],
        &StateMeta {
            writable: true,
            ..Default::default()
        },
    );
    let mut publisher = StatePublisher::create(&bus, "sys", &specs).unwrap();
    let mut commands = CommandReceiver::create(&bus, "sys").unwrap();
    let mut sub = StateSubscriber::with_buffer(&bus, "sys/a", 64).unwrap();
    let mut ctl = Controller::new(&bus);
    ctl.add_ctrl("sys/a", 1.0).unwrap();
    ctl.add_ctrl("sys/b", 2.0).unwrap();

    // Warm-up: connections are established lazily on the first sends.
    for tick in 0..10 {
        for k in 0..3 {
            publisher.publish(k, tick, monotonic_ns(), 0.0, 0).unwrap();
        }
        publisher.notify_tick().unwrap();
        ctl.add_ctrl("sys/a", 1.0).unwrap();
        ctl.send_ctrl().unwrap();
        commands.drain(|_| {}).unwrap();
        sub.drain(|_| {}).unwrap();
    }

    let mut frames = 0;
    let mut setpoints = 0.0;
    let (_, allocations) = measure(|| {
        for tick in 10..10_010u64 {
            for k in 0..3 {
                publisher
                    .publish(k, tick, monotonic_ns(), tick as f64, 0)
                    .unwrap();
            }
            publisher.notify_tick().unwrap();
            if tick % 10 == 0 {
                ctl.add_ctrl("sys/a", tick as f64).unwrap();
                ctl.add_ctrl("sys/b", 2.0).unwrap();
                ctl.send_ctrl().unwrap();
            }
            frames += commands
                .drain(|f| setpoints += f.setpoints().iter().map(|s| s.value).sum::<f64>())
                .unwrap();
            sub.drain(|_| {}).unwrap();
        }
    });
    assert_eq!(frames, 1000, "every frame was drained");
    assert!(setpoints > 0.0);
    assert_eq!(sub.missed(), 0);
    assert_eq!(allocations, 0, "the per-tick path allocated");

    // A bad index is refused on the same path, without allocating either.
    let (refused, allocations) = measure(|| publisher.publish(3, 0, monotonic_ns(), 0.0, 0));
    assert!(
        matches!(
            refused,
            Err(conductor_bus::BusError::NoSuchIndex { index: 3, count: 3 })
        ),
        "{refused:?}"
    );
    assert_eq!(allocations, 0, "refusing a bad index allocated");
}

/// An iceoryx2 failure on the per-tick path (a loan or a send refused) becomes a `BusError`
/// without allocating: the context is a literal and the cause iceoryx2's own `Copy` enum, which
/// a caller matches on as a value, not as text.
#[test]
fn an_iceoryx2_error_on_the_tick_path_allocates_nothing() {
    use conductor_bus::{BusError, IceoryxError};
    use iceoryx2::port::{LoanError, SendError};

    let (errors, allocations) = measure(|| {
        [
            BusError::iceoryx("loaning a state sample", LoanError::ExceedsMaxLoans),
            BusError::iceoryx(
                "sending a state sample",
                SendError::LoanError(LoanError::OutOfMemory),
            ),
        ]
    });
    assert_eq!(allocations, 0, "building the errors allocated");
    assert_eq!(
        errors[0].iceoryx_source(),
        Some(IceoryxError::Loan(LoanError::ExceedsMaxLoans))
    );
    assert!(matches!(
        errors[1],
        BusError::Iceoryx {
            source: IceoryxError::Send(SendError::LoanError(LoanError::OutOfMemory)),
            ..
        }
    ));
    // The text for people still says what was being done and what iceoryx2 said, and the
    // cause is reachable as the error's source.
    assert_eq!(
        errors[0].to_string(),
        "loaning a state sample: LoanError::ExceedsMaxLoans"
    );
    let source = std::error::Error::source(&errors[0]).expect("a typed source");
    assert_eq!(source.to_string(), "LoanError::ExceedsMaxLoans");
}
