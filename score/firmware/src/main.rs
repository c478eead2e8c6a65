//! Score on the RP2040 (Raspberry Pi Pico): the thesis' signal-variable machine on Embassy.
//!
//! ```text
//!  USB ─┬─ CDC 0: terminal ──► terminal_task ──┐  (lines → Board::run_line, text back)
//!       └─ CDC 1: link ──────► link_rx_task ───┤  (score_link requests → replies)
//!                              link_tx_task ◄──┼── LINK_TX (whole frames: replies, samples,
//!                                              │            table changes)
//!                              engine_task ────┘  tick at each deadline, then the subscribed
//!                                                 samples and table changes
//! ```
//!
//! All tasks run on one thread-mode executor and share the [`Board`] through a blocking mutex
//! held only for synchronous work (never across an `await`). The engine task sleeps until the
//! next deadline or until a command wakes it (`WAKE`).
#![no_std]
#![no_main]

mod io;

use core::cell::RefCell;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use embassy_executor::Spawner;
use embassy_futures::select::{select, Either};
use embassy_rp::adc::{self, Adc, Channel};
use embassy_rp::bind_interrupts;
use embassy_rp::gpio::{Flex, Pull};
use embassy_rp::peripherals::USB;
use embassy_rp::usb::{Driver, InterruptHandler};
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::channel::Channel as Queue;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use embassy_usb::class::cdc_acm::{self, CdcAcmClass};
use embassy_usb::driver::EndpointError;
use embassy_usb::UsbDevice;
use panic_halt as _;
use static_cell::StaticCell;

use conductor_protocols::score_link::{Reply, SampleBatch, MAX_FRAME};
use score_board::bench::pid_cycles;
use score_board::hal::BoardHal;
use score_board::link::LinkServer;
use score_board::out::{FrameOut, TextOut};
use score_board::terminal::Terminal;
use score_board::{Board, BoardInfo};
use score_core::Num;

use io::RpIo;

bind_interrupts!(struct Irqs {
    USBCTRL_IRQ => InterruptHandler<USB>;
});

type Drv = Driver<'static, USB>;
type ScoreBoard = Board<Num, BoardHal<RpIo>>;
type Shared = Mutex<ThreadModeRawMutex, RefCell<ScoreBoard>>;
type Frame = heapless::Vec<u8, MAX_FRAME>;

/// Board name: the USB serial number and the gateway's default subsystem `score-<name>`.
const BOARD_NAME: &str = match option_env!("SCORE_BOARD_NAME") {
    Some(n) => n,
    None => "rp2040",
};
const INFO: BoardInfo = BoardInfo {
    firmware: concat!("score-firmware ", env!("CARGO_PKG_VERSION")),
    board: BOARD_NAME,
};
/// pid.codes test VID/PID: fine for a lab, not for products (see README).
const USB_VID: u16 = 0x1209;
const USB_PID: u16 = 0x0001;
/// SysTick is a 24-bit down-counter of CPU cycles.
const SYST_MASK: u32 = 0x00FF_FFFF;

static BOARD: StaticCell<Shared> = StaticCell::new();
/// Something changed (a definition, a subscription): the engine task recomputes its deadline.
static WAKE: Signal<ThreadModeRawMutex, ()> = Signal::new();
/// Whole frames for the link's IN endpoint.
static LINK_TX: Queue<ThreadModeRawMutex, Frame, 12> = Queue::new();

#[embassy_executor::main(
    executor = "embassy_rp::executor::Executor",
    entry = "cortex_m_rt::entry"
)]
async fn main(spawner: Spawner) {
    let p = embassy_rp::init(Default::default());
    if let Some(mut cp) = cortex_m::Peripherals::take() {
        start_cycle_counter(&mut cp.SYST);
    }

    let io = RpIo {
        adc: Adc::new_blocking(p.ADC, adc::Config::default()),
        channels: [
            Channel::new_pin(p.PIN_26, Pull::None),
            Channel::new_pin(p.PIN_27, Pull::None),
            Channel::new_pin(p.PIN_28, Pull::None),
            Channel::new_pin(p.PIN_29, Pull::None),
            Channel::new_temp_sensor(p.ADC_TEMP_SENSOR),
        ],
        pins: [
            Flex::new(p.PIN_0),
            Flex::new(p.PIN_1),
            Flex::new(p.PIN_2),
            Flex::new(p.PIN_3),
            Flex::new(p.PIN_4),
            Flex::new(p.PIN_5),
            Flex::new(p.PIN_6),
            Flex::new(p.PIN_7),
            Flex::new(p.PIN_8),
            Flex::new(p.PIN_9),
            Flex::new(p.PIN_10),
            Flex::new(p.PIN_11),
            Flex::new(p.PIN_12),
            Flex::new(p.PIN_13),
            Flex::new(p.PIN_14),
            Flex::new(p.PIN_15),
            Flex::new(p.PIN_16),
            Flex::new(p.PIN_17),
            Flex::new(p.PIN_18),
            Flex::new(p.PIN_19),
            Flex::new(p.PIN_20),
            Flex::new(p.PIN_21),
            Flex::new(p.PIN_22),
            Flex::new(p.PIN_23),
            Flex::new(p.PIN_24),
            Flex::new(p.PIN_25),
        ],
        _slices: (
            p.PWM_SLICE0,
            p.PWM_SLICE1,
            p.PWM_SLICE2,
            p.PWM_SLICE3,
            p.PWM_SLICE4,
            p.PWM_SLICE5,
            p.PWM_SLICE6,
            p.PWM_SLICE7,
        ),
        sys_hz: embassy_rp::clocks::clk_sys_freq(),
    };
    let board: &'static Shared =
        BOARD.init_with(|| Mutex::new(RefCell::new(Board::new(BoardHal::new(io), INFO))));

    let driver = Driver::new(p.USB, Irqs);
    let mut config = embassy_usb::Config::new(USB_VID, USB_PID);
    config.manufacturer = Some("Conductor");
    config.product = Some("Score RP2040");
    config.serial_number = Some(BOARD_NAME);
    config.max_power = 100;
    config.max_packet_size_0 = 64;
    // Two CDC functions: interface association descriptors (Windows needs them; Linux is happy).
    config.composite_with_iads = true;
    config.device_class = 0xEF;
    config.device_sub_class = 0x02;
    config.device_protocol = 0x01;

    static CONFIG_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    static TERM_STATE: StaticCell<cdc_acm::State> = StaticCell::new();
    static LINK_STATE: StaticCell<cdc_acm::State> = StaticCell::new();
    let mut builder = embassy_usb::Builder::new(
        driver,
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 256]),
        &mut [],
        CONTROL_BUF.init([0; 64]),
    );
    let term = CdcAcmClass::new(&mut builder, TERM_STATE.init(cdc_acm::State::new()), 64);
    let link = CdcAcmClass::new(&mut builder, LINK_STATE.init(cdc_acm::State::new()), 64);
    let usb = builder.build();

    let (link_tx, link_rx) = link.split();
    spawner.spawn(usb_task(usb).unwrap());
    spawner.spawn(engine_task(board).unwrap());
    spawner.spawn(terminal_task(term, board).unwrap());
    spawner.spawn(link_rx_task(link_rx, board).unwrap());
    spawner.spawn(link_tx_task(link_tx).unwrap());
}

fn start_cycle_counter(syst: &mut SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYST_MASK);
    syst.clear_current();
    syst.enable_counter();
}

fn now_us() -> u64 {
    Instant::now().as_micros()
}

#[embassy_executor::task]
async fn usb_task(mut usb: UsbDevice<'static, Drv>) -> ! {
    usb.run().await
}

/// Runs every update when due, then queues the subscribed samples and table changes.
#[embassy_executor::task]
async fn engine_task(board: &'static Shared) -> ! {
    loop {
        let now = now_us();
        let next = board.lock(|b| {
            let mut b = b.borrow_mut();
            b.tick(now);
            if let Some(generation) = b.take_table_change() {
                queue_reply(&Reply::TableChanged { generation });
            }
            let lost_before = b.sampler.lost();
            let mut lost = 0u32;
            b.collect_samples(now, |t, samples| {
                if !queue_reply(&Reply::Samples(SampleBatch::new(t, lost_before, samples))) {
                    lost += samples.len() as u32;
                }
            });
            b.sampler.note_lost(lost);
            b.next_wake()
        });
        match next {
            Some(t) if t <= now_us() => {}
            Some(t) => {
                let _ = select(Timer::at(Instant::from_micros(t)), WAKE.wait()).await;
            }
            None => WAKE.wait().await,
        }
    }
}

/// Encodes and queues a frame without waiting; false if the queue is full.
fn queue_reply(reply: &Reply<'_>) -> bool {
    let mut buf = [0u8; MAX_FRAME];
    match conductor_protocols::score_link::encode_reply(0, reply, &mut buf) {
        Ok(n) => Frame::from_slice(&buf[..n])
            .ok()
            .is_some_and(|f| LINK_TX.try_send(f).is_ok()),
        Err(_) => false,
    }
}

/// Sends `bytes` as 64-byte packets; a transfer that ends on a full packet gets a zero-length
/// packet so the host sees its end.
async fn write_all(
    tx: &mut cdc_acm::Sender<'static, Drv>,
    bytes: &[u8],
    end_transfer: bool,
) -> Result<(), EndpointError> {
    for chunk in bytes.chunks(64) {
        tx.write_packet(chunk).await?;
    }
    if end_transfer && !bytes.is_empty() && bytes.len().is_multiple_of(64) {
        tx.write_packet(&[]).await?;
    }
    Ok(())
}

/// The firmware's own commands, available on the terminal and through the link's `Exec`.
fn extra_commands(line: &str, out: &mut dyn core::fmt::Write) -> Option<bool> {
    let mut words = line.split_whitespace();
    match words.next()? {
        "bench" => {
            let updates = match words.next().map(str::parse::<u32>) {
                None => 1000,
                Some(Ok(n)) if (1..=100_000).contains(&n) => n,
                Some(_) => {
                    let _ = writeln!(out, "error: bench: expected a number of updates (1-100000)");
                    return Some(false);
                }
            };
            let _ = writeln!(
                out,
                "bench: Fig. 5.20 PID, {updates} updates at 1 kHz, CPU cycles per update (SysTick)"
            );
            let mut counter = SYST::get_current;
            for (name, r) in [
                ("f32", {
                    let t0 = now_us();
                    pid_cycles::<f32>(updates, SYST_MASK, &mut counter).map(|s| (s, now_us() - t0))
                }),
                ("f64", {
                    let t0 = now_us();
                    pid_cycles::<f64>(updates, SYST_MASK, &mut counter).map(|s| (s, now_us() - t0))
                }),
            ] {
                match r {
                    Ok((s, us)) => {
                        let _ = writeln!(
                            out,
                            "bench {name}: min {} mean {:.0} max {} cycles; {} us in all",
                            s.min,
                            s.mean(),
                            s.max,
                            us
                        );
                    }
                    Err(e) => {
                        let _ = writeln!(out, "error: bench {name}: {e}");
                        return Some(false);
                    }
                }
            }
            Some(true)
        }
        "board" => {
            let _ = writeln!(
                out,
                "board '{}', {}, clk_sys {} Hz, numbers {}, engine table {} bytes",
                INFO.board,
                INFO.firmware,
                embassy_rp::clocks::clk_sys_freq(),
                <Num as score_core::Real>::NAME,
                score_core::ENGINE_BYTES
            );
            let _ = writeln!(
                out,
                "ADC 0-3 on GPIO 26-29 (12 bit, 3.3 V), T = temperature sensor, pairs A = 0-1, B = 2-3 (in software)"
            );
            let _ = writeln!(
                out,
                "PWM outputs 0-15 on GPIO 0-15 (slice n/2), pairs A-H = slice 0-7 with B inverted; gpio pins 0-25"
            );
            Some(true)
        }
        _ => None,
    }
}

/// The human terminal on CDC 0: banner when DTR rises (a terminal opened the port), echo,
/// one command per line.
#[embassy_executor::task]
async fn terminal_task(class: CdcAcmClass<'static, Drv>, board: &'static Shared) -> ! {
    let (mut tx, mut rx, control) = class.split_with_control();
    let mut term = Terminal::new();
    let mut out = TextOut::<4096>::new(true);
    let mut buf = [0u8; 64];
    loop {
        rx.wait_connection().await;
        let mut dtr = false;
        loop {
            out.clear();
            match select(rx.read_packet(&mut buf), control.control_changed()).await {
                Either::First(Ok(n)) => {
                    let ran = board.lock(|b| {
                        term.feed(
                            &buf[..n],
                            &mut b.borrow_mut(),
                            now_us(),
                            &mut out,
                            &mut extra_commands,
                        )
                    });
                    if ran {
                        WAKE.signal(());
                    }
                }
                Either::First(Err(_)) => break,
                Either::Second(()) => {
                    let now_dtr = control.dtr();
                    if now_dtr && !dtr {
                        board.lock(|b| term.banner(&b.borrow(), &mut out));
                    }
                    dtr = now_dtr;
                }
            }
            if write_all(&mut tx, out.as_bytes(), true).await.is_err() {
                break;
            }
        }
    }
}

/// Requests from the gateway on CDC 1, answered into `LINK_TX`.
#[embassy_executor::task]
async fn link_rx_task(mut rx: cdc_acm::Receiver<'static, Drv>, board: &'static Shared) -> ! {
    let mut server = LinkServer::new();
    let mut out = FrameOut::<6144>::new();
    let mut buf = [0u8; 64];
    loop {
        rx.wait_connection().await;
        server.reset();
        while let Ok(n) = rx.read_packet(&mut buf).await {
            out.clear();
            let woke = board.lock(|b| {
                server.feed(
                    &buf[..n],
                    &mut b.borrow_mut(),
                    now_us(),
                    &mut out,
                    &mut extra_commands,
                )
            });
            if woke {
                WAKE.signal(());
            }
            for f in out.frames() {
                if let Ok(frame) = Frame::from_slice(f) {
                    LINK_TX.send(frame).await;
                }
            }
        }
    }
}

/// Writes queued frames to CDC 1.
#[embassy_executor::task]
async fn link_tx_task(mut tx: cdc_acm::Sender<'static, Drv>) -> ! {
    loop {
        let frame = LINK_TX.receive().await;
        if write_all(&mut tx, &frame, LINK_TX.is_empty())
            .await
            .is_err()
        {
            tx.wait_connection().await;
        }
    }
}
