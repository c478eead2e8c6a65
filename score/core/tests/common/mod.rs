//! Test board: the dummy HAL's peripherals plus in-memory playback and log files.
#![allow(dead_code)]

use score_core::hal::*;
use score_core::{Engine, Num, Outcome};

/// [`DummyHal`]'s peripherals beside named in-memory playback inputs and logs.
pub type MemBoard = Board<DummyHal, MemFiles>;

/// An empty engine and a fresh [`board`], as every test starts.
pub fn engine_and_board() -> (Engine<Num>, MemBoard) {
    (Engine::new(), board())
}

/// A test board: every ADC conversion reads 0 and every pin reads high (set `hw.adc_code`,
/// `hw.pin_level` for others), no files yet.
pub fn board() -> MemBoard {
    Board::new(
        DummyHal {
            adc_code: 0,
            pin_level: true,
            ..DummyHal::default()
        },
        MemFiles::default(),
    )
}

/// `infile` inputs given by the test, `log` outputs kept as lines.
#[derive(Default)]
pub struct MemFiles {
    pub inputs: Vec<(String, Vec<f64>)>,
    pub open: Vec<Option<usize>>,
    pub logs: Vec<(String, Vec<String>)>,
    pub log_open: Vec<Option<usize>>,
}

impl MemFiles {
    /// `infile` of `path` will play `data`.
    pub fn add_input(&mut self, path: &str, data: Vec<f64>) {
        self.inputs.push((path.into(), data));
    }
    /// The numbers last logged to `path`.
    pub fn log(&self, path: &str) -> Vec<f64> {
        let (_, lines) = self
            .logs
            .iter()
            .rev()
            .find(|(p, _)| p == path)
            .expect("log exists");
        lines.iter().map(|l| l.parse().expect("number")).collect()
    }
}

impl DataFiles for MemFiles {
    fn open_input(&mut self, path: &str) -> Result<StreamId, HalError> {
        let i = self
            .inputs
            .iter()
            .position(|(p, _)| p == path)
            .ok_or(HalError::Io)?;
        self.open.push(Some(i));
        Ok(StreamId((self.open.len() - 1) as u8))
    }
    fn input_len(&self, id: StreamId) -> u32 {
        self.open[id.0 as usize].map_or(0, |i| self.inputs[i].1.len() as u32)
    }
    fn input_sample(&self, id: StreamId, index: u32) -> f64 {
        self.open[id.0 as usize].map_or(0.0, |i| self.inputs[i].1[index as usize])
    }
    fn open_log(&mut self, path: &str) -> Result<StreamId, HalError> {
        self.logs.push((path.into(), Vec::new()));
        self.open.push(None);
        self.log_open.resize(self.open.len(), None);
        self.log_open[self.open.len() - 1] = Some(self.logs.len() - 1);
        Ok(StreamId((self.open.len() - 1) as u8))
    }
    fn write_log(&mut self, id: StreamId, text: &str) {
        if let Some(Some(i)) = self.log_open.get(id.0 as usize) {
            self.logs[*i].1.push(text.to_string());
        }
    }
    fn close(&mut self, id: StreamId) {
        if let Some(slot) = self.open.get_mut(id.0 as usize) {
            *slot = None;
        }
        if let Some(slot) = self.log_open.get_mut(id.0 as usize) {
            *slot = None;
        }
    }
}

/// Runs lines, panicking with the message on error; returns the output.
pub fn run(e: &mut Engine<Num>, hal: &mut MemBoard, lines: &str) -> String {
    let mut out = String::new();
    for line in lines.lines() {
        match e.execute(line, hal, &mut out) {
            Ok(Outcome::Done) => {}
            Ok(o) => panic!("unexpected outcome {o:?} for {line}"),
            Err(err) => panic!("{line}: {err}"),
        }
    }
    out
}

/// Runs a line that must be refused; returns the refusal's message.
pub fn refused(e: &mut Engine<Num>, hal: &mut MemBoard, line: &str) -> String {
    match e.execute(line, hal, &mut String::new()) {
        Ok(o) => panic!("{line}: not refused ({o:?})"),
        Err(err) => err.to_string(),
    }
}

/// [`refused`], and the table is as it was before the line.
pub fn refused_unchanged(e: &mut Engine<Num>, hal: &mut MemBoard, line: &str) -> String {
    let before = e.clone();
    let err = refused(e, hal, line);
    assert_eq!(*e, before, "{line}: refused, but the table changed");
    err
}

/// Simulated time: runs every due update with deadline < `until_us`.
pub fn run_until(e: &mut Engine<Num>, hal: &mut MemBoard, until_us: u64) {
    while let Some(t) = e.next_deadline() {
        if t >= until_us {
            break;
        }
        e.tick(t, hal);
    }
}
