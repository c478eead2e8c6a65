//! Seeded fault injection on byte streams: corrupt, drop, delay and truncate, each at a given
//! rate, with a record of exactly what was done so tests can reconcile counters with it.

/// A small, fast, seedable generator (SplitMix64): tests must be reproducible, and the
/// injector must not depend on a crate's stream changing between versions.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.unit() < p
    }

    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }
}

/// Fault rates. Byte faults apply to each byte independently; packet faults to each packet
/// (each chunk handed to [`FaultInjector::apply`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FaultConfig {
    /// Probability that a byte is corrupted (XORed with a random non-zero value).
    pub corrupt: f64,
    /// Probability that a byte is lost.
    pub drop: f64,
    /// Probability that a packet is delayed by `delay_ns`.
    pub delay: f64,
    /// Delay of a delayed packet.
    pub delay_ns: u64,
    /// Probability that a packet loses a random-length tail (at least one byte).
    pub truncate: f64,
    /// Seed of the generator.
    pub seed: u64,
}

impl FaultConfig {
    /// Whether any fault can happen.
    pub fn is_active(&self) -> bool {
        self.corrupt > 0.0 || self.drop > 0.0 || self.delay > 0.0 || self.truncate > 0.0
    }
}

/// What the injector did to one packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FaultRecord {
    /// Bytes corrupted.
    pub corrupted: u32,
    /// Bytes dropped (truncation included).
    pub dropped: u32,
    /// The tail was cut.
    pub truncated: bool,
    /// The packet was delayed.
    pub delayed: bool,
}

impl FaultRecord {
    /// Whether the bytes that arrive differ from the bytes sent.
    pub fn damaged(&self) -> bool {
        self.corrupted > 0 || self.dropped > 0
    }
}

/// Totals since creation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FaultTotals {
    /// Packets seen.
    pub packets: u64,
    /// Packets whose bytes were changed.
    pub damaged_packets: u64,
    /// Packets delayed.
    pub delayed_packets: u64,
    /// Bytes corrupted.
    pub corrupted_bytes: u64,
    /// Bytes dropped.
    pub dropped_bytes: u64,
}

/// Applies [`FaultConfig`] to packets.
#[derive(Debug, Clone)]
pub struct FaultInjector {
    cfg: FaultConfig,
    rng: Rng,
    totals: FaultTotals,
}

impl FaultInjector {
    /// An injector with its own generator seeded from `cfg.seed`.
    pub fn new(cfg: FaultConfig) -> Self {
        Self {
            rng: Rng::new(cfg.seed),
            cfg,
            totals: FaultTotals::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &FaultConfig {
        &self.cfg
    }

    /// Totals since creation.
    pub fn totals(&self) -> FaultTotals {
        self.totals
    }

    /// Damages `packet` in place per the rates; returns what was done and the delay to add.
    /// The packet shrinks by the dropped bytes.
    pub fn apply(&mut self, packet: &mut Vec<u8>) -> (FaultRecord, u64) {
        let mut rec = FaultRecord::default();
        self.totals.packets += 1;
        if !self.cfg.is_active() {
            return (rec, 0);
        }
        if !packet.is_empty() && self.rng.chance(self.cfg.truncate) {
            let cut = 1 + self.rng.below(packet.len() as u64) as usize;
            packet.truncate(packet.len() - cut);
            rec.truncated = true;
            rec.dropped += cut as u32;
        }
        let mut i = 0;
        while i < packet.len() {
            if self.rng.chance(self.cfg.drop) {
                packet.remove(i);
                rec.dropped += 1;
                continue;
            }
            if self.rng.chance(self.cfg.corrupt) {
                packet[i] ^= 1 + self.rng.below(255) as u8;
                rec.corrupted += 1;
            }
            i += 1;
        }
        let delay = if self.rng.chance(self.cfg.delay) {
            rec.delayed = true;
            self.totals.delayed_packets += 1;
            self.cfg.delay_ns
        } else {
            0
        };
        self.totals.corrupted_bytes += rec.corrupted as u64;
        self.totals.dropped_bytes += rec.dropped as u64;
        if rec.damaged() {
            self.totals.damaged_packets += 1;
        }
        (rec, delay)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_are_honoured_and_reproducible() {
        let cfg = FaultConfig {
            corrupt: 0.01,
            drop: 0.02,
            seed: 7,
            ..FaultConfig::default()
        };
        let run = || {
            let mut f = FaultInjector::new(cfg);
            for _ in 0..1000 {
                let mut p = vec![0x55u8; 100];
                let (rec, _) = f.apply(&mut p);
                assert_eq!(p.len(), 100 - rec.dropped as usize);
                assert_eq!(
                    p.iter().filter(|&&b| b != 0x55).count(),
                    rec.corrupted as usize,
                    "a corrupted byte always changes"
                );
            }
            f.totals()
        };
        let t = run();
        assert_eq!(t, run(), "same seed, same faults");
        // 100 000 bytes: binomial means 1000 and 2000 (± ~32 and ~44 one sigma); 5 sigma.
        assert!((t.corrupted_bytes as i64 - 990).abs() < 160, "{t:?}");
        assert!((t.dropped_bytes as i64 - 2000).abs() < 225, "{t:?}");
    }

    #[test]
    fn truncation_and_delay() {
        let mut f = FaultInjector::new(FaultConfig {
            truncate: 1.0,
            delay: 1.0,
            delay_ns: 5,
            seed: 1,
            ..FaultConfig::default()
        });
        let mut p = vec![1u8; 10];
        let (rec, delay) = f.apply(&mut p);
        assert!(rec.truncated && rec.delayed && rec.damaged());
        assert_eq!(delay, 5);
        assert!(p.len() < 10);
    }
}
