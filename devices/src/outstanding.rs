//! Requests awaiting replies, so a protocol can report the ones that never come.

use crate::message::{Credential, Op, Reply, ReplyData, Request};
use crate::queue::Bounded;

/// One request in flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pending {
    /// Who should answer.
    pub cred: Credential,
    /// What was asked.
    pub op: Op,
    /// Tick of the request.
    pub tick: u64,
    /// When it was asked (the sample time of its answer).
    pub t_request_ns: u64,
    /// When to give up (CLOCK_MONOTONIC ns).
    pub deadline_ns: u64,
}

impl Pending {
    /// Request `r`, given up at `deadline_ns`.
    pub fn new(r: &Request, deadline_ns: u64) -> Self {
        Self {
            cred: r.cred,
            op: r.op,
            tick: r.tick,
            t_request_ns: r.t_request_ns,
            deadline_ns,
        }
    }

    /// The reply that answers this request with `data` (sampled when it was asked).
    pub fn reply(&self, data: ReplyData) -> Reply {
        Reply {
            cred: self.cred,
            data,
            tick: self.tick,
            t_sample_ns: self.t_request_ns,
        }
    }
}

/// Fixed-capacity table of requests in flight.
#[derive(Debug, Clone)]
pub struct Outstanding {
    pending: Bounded<Pending>,
}

impl Outstanding {
    /// Room for `capacity` requests in flight.
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            pending: Bounded::with_capacity(capacity),
        }
    }

    /// Registers a request; `false` if the table is full (the caller counts a dropped request).
    pub fn track(&mut self, p: Pending) -> bool {
        self.pending.push(p).is_ok()
    }

    /// Removes and returns the oldest pending request from `cred` that `matches`.
    pub fn resolve(&mut self, cred: Credential, matches: impl Fn(&Op) -> bool) -> Option<Pending> {
        let i = self
            .pending
            .as_slice()
            .iter()
            .position(|p| p.cred == cred && matches(&p.op))?;
        Some(self.pending.remove(i))
    }

    /// Moves every request past its deadline into `out` as [`ReplyData::Missing`]; returns how
    /// many expired.
    pub fn expire(&mut self, now_ns: u64, out: &mut Bounded<Reply>) -> u64 {
        let mut expired = 0;
        self.pending.retain(|p| {
            if p.deadline_ns > now_ns {
                return true;
            }
            expired += 1;
            let _ = out.push(p.reply(ReplyData::Missing { op: p.op }));
            false
        });
        expired
    }

    /// Requests in flight.
    pub fn len(&self) -> usize {
        self.pending.len()
    }

    /// Whether nothing is in flight.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// Forgets everything (e.g. after the bus was reset).
    pub fn clear(&mut self) {
        self.pending.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(id: u32, tick: u64, deadline: u64) -> Pending {
        Pending {
            cred: Credential::id(id),
            op: Op::Sample,
            tick,
            t_request_ns: tick * 10,
            deadline_ns: deadline,
        }
    }

    #[test]
    fn resolve_in_order_and_expire_the_rest() {
        let mut o = Outstanding::with_capacity(8);
        assert!(o.track(p(1, 1, 100)));
        assert!(o.track(p(2, 1, 100)));
        assert!(o.track(p(1, 2, 200)));
        assert!(o.track(p(3, 2, 300)));
        let r = o.resolve(Credential::id(1), |_| true).unwrap();
        assert_eq!(r.tick, 1, "oldest first");
        assert_eq!(o.len(), 3);
        let mut out = Bounded::with_capacity(8);
        assert_eq!(o.expire(250, &mut out), 2);
        let expired: Vec<(u32, u64)> = out.as_slice().iter().map(|r| (r.cred.id, r.tick)).collect();
        assert_eq!(expired, [(2, 1), (1, 2)]);
        assert!(matches!(out.as_slice()[0].data, ReplyData::Missing { .. }));
        assert_eq!(o.len(), 1);
        assert_eq!(o.resolve(Credential::id(3), |_| true).unwrap().tick, 2);
        assert!(o.is_empty());
        assert!(o.resolve(Credential::id(3), |_| true).is_none());
    }

    #[test]
    fn full_table_refuses() {
        let mut o = Outstanding::with_capacity(1);
        assert!(o.track(p(1, 1, 1)));
        assert!(!o.track(p(2, 1, 1)));
    }
}
