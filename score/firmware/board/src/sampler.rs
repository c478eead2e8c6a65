//! Subscriptions of the link: which variables to send, how often, stamped with the instant
//! their value was produced.
//!
//! * A **periodic** variable (ADC, integral, PID, PWM follower, ...) is sent right after an
//!   update, stamped with that update's scheduled instant ([`Engine::last_update_us`]), and
//!   decimated to the subscription period: an update is sent if it falls at least the period
//!   (less half the variable's own period, for jitter) after the last one sent.
//! * A **bare expression** has no instant of its own: it is evaluated every subscription period
//!   and stamped with the evaluation time.
//!
//! A subscription belongs to the table generation it was made in; when the table changes it
//! lapses (the slot may hold another variable now) and the host lists and subscribes again.

use score_core::hal::Hal;
use score_core::{Engine, Real, VarId};

use conductor_protocols::score_link::MAX_SAMPLES;

/// Subscriptions held at once (one per variable).
pub const MAX_SUBSCRIPTIONS: usize = score_core::capacity::MAX_SYMBOLS;
/// Shortest subscription period, µs (10 kHz).
pub const MIN_PERIOD_US: u32 = 100;

#[derive(Debug, Clone, Copy, PartialEq)]
struct Sub {
    id: VarId,
    period_us: u32,
    generation: u32,
    next_due: u64,
    last_sent: Option<u64>,
}

/// No free slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Full;

/// The subscription table and the count of samples lost on the way out.
#[derive(Debug, Clone)]
pub struct Sampler {
    subs: [Option<Sub>; MAX_SUBSCRIPTIONS],
    lost: u32,
}

impl Default for Sampler {
    fn default() -> Self {
        Self::new()
    }
}

impl Sampler {
    /// No subscriptions.
    pub const fn new() -> Self {
        Self {
            subs: [None; MAX_SUBSCRIPTIONS],
            lost: 0,
        }
    }

    /// Sends `id` every `period_us` (raised to [`MIN_PERIOD_US`]) from `now_us` on; replaces an
    /// existing subscription of `id`.
    pub fn subscribe(
        &mut self,
        id: VarId,
        period_us: u32,
        generation: u32,
        now_us: u64,
    ) -> Result<(), Full> {
        let sub = Sub {
            id,
            period_us: period_us.max(MIN_PERIOD_US),
            generation,
            next_due: now_us,
            last_sent: None,
        };
        let slot = match self.subs.iter().position(|s| s.is_some_and(|s| s.id == id)) {
            Some(i) => i,
            None => self.subs.iter().position(Option::is_none).ok_or(Full)?,
        };
        self.subs[slot] = Some(sub);
        Ok(())
    }

    /// Stops sending `id`.
    pub fn unsubscribe(&mut self, id: VarId) {
        for s in &mut self.subs {
            if s.is_some_and(|s| s.id == id) {
                *s = None;
            }
        }
    }

    /// Stops everything.
    pub fn clear(&mut self) {
        self.subs = [None; MAX_SUBSCRIPTIONS];
    }

    /// Number of subscriptions.
    pub fn len(&self) -> usize {
        self.subs.iter().flatten().count()
    }

    /// True if there are none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Samples lost so far (counted by the port when its queue was full).
    pub fn lost(&self) -> u32 {
        self.lost
    }

    /// Counts `n` samples the port could not send.
    pub fn note_lost(&mut self, n: u32) {
        self.lost = self.lost.saturating_add(n);
    }

    /// When the next bare-expression sample falls due (periodic variables are sampled after
    /// the engine's own updates).
    pub fn next_due<N: Real>(&self, engine: &Engine<N>) -> Option<u64> {
        self.subs
            .iter()
            .flatten()
            .filter(|s| s.generation == engine.generation() && !periodic(engine, s.id))
            .map(|s| s.next_due)
            .min()
    }

    /// Collects what is due at `now_us` and hands it to `emit` as batches `(t_us, samples)`,
    /// oldest instant first, at most [`MAX_SAMPLES`] per batch.
    pub fn collect<N: Real>(
        &mut self,
        engine: &mut Engine<N>,
        _hal: &mut impl Hal,
        now_us: u64,
        mut emit: impl FnMut(u64, &[(u8, f64)]),
    ) {
        let generation = engine.generation();
        let mut due = [(0u64, 0u8, 0f64); MAX_SUBSCRIPTIONS];
        let mut n = 0;
        for slot in self.subs.iter_mut() {
            let Some(s) = slot else { continue };
            if s.generation != generation || engine.info(s.id).is_none() {
                *slot = None;
                continue;
            }
            let rate = engine.info(s.id).and_then(|i| i.rate_hz);
            let t = match rate {
                Some(hz) => {
                    let Some(u) = engine.last_update_us(s.id) else {
                        continue;
                    };
                    let own = (1e6 / hz) as u64;
                    let min_gap =
                        (s.period_us as u64).saturating_sub(own.min(s.period_us as u64) / 2);
                    match s.last_sent {
                        Some(l) if u <= l || u - l < min_gap => continue,
                        _ => u,
                    }
                }
                None => {
                    if now_us < s.next_due {
                        continue;
                    }
                    s.next_due += s.period_us as u64;
                    if s.next_due <= now_us {
                        s.next_due = now_us + s.period_us as u64;
                    }
                    now_us
                }
            };
            s.last_sent = Some(t);
            let v = engine.value(s.id).map_or(f64::NAN, |v| v.to_f64());
            due[n] = (t, s.id.0, v);
            n += 1;
        }
        let due = &mut due[..n];
        // Insertion sort by instant (at most MAX_SUBSCRIPTIONS entries, no allocation).
        for a in 1..due.len() {
            let mut b = a;
            while b > 0 && due[b - 1].0 > due[b].0 {
                due.swap(b - 1, b);
                b -= 1;
            }
        }
        let mut batch = [(0u8, 0f64); MAX_SAMPLES];
        let mut i = 0;
        while i < due.len() {
            let t = due[i].0;
            let mut k = 0;
            while i < due.len() && due[i].0 == t && k < MAX_SAMPLES {
                batch[k] = (due[i].1, due[i].2);
                k += 1;
                i += 1;
            }
            emit(t, &batch[..k]);
        }
    }
}

fn periodic<N: Real>(engine: &Engine<N>, id: VarId) -> bool {
    engine.info(id).is_some_and(|i| i.rate_hz.is_some())
}
