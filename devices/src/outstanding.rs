//! Requests awaiting replies, so a protocol can report the ones that never come, match each
//! reply to the request that caused it (never to one sent after the reply arrived), and tell a
//! late reply from a stranger's frame.

use std::collections::VecDeque;

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
    /// Stream position just after its words: a reply that arrived below it predates it.
    pub end_pos: u64,
}

impl Pending {
    /// Request `r`, whose words end at stream position `end_pos`, given up at `deadline_ns`.
    pub fn new(r: &Request, deadline_ns: u64, end_pos: u64) -> Self {
        Self {
            cred: r.cred,
            op: r.op,
            tick: r.tick,
            t_request_ns: r.t_request_ns,
            deadline_ns,
            end_pos,
        }
    }

    /// The reply that answers this request with `data` (sampled when it was asked).
    pub fn reply(&self, data: ReplyData) -> Reply {
        Reply::answer(self.cred, self.op, data, self.tick, self.t_request_ns)
    }

    /// The answer `data`, sampled at the reply's arrival `t_rx_ns` where it is known (not
    /// before the request: clocks of different sources may disagree by a little), else at
    /// the request's time.
    pub fn reply_at(&self, data: ReplyData, t_rx_ns: u64) -> Reply {
        let t = if t_rx_ns == 0 {
            self.t_request_ns
        } else {
            t_rx_ns.max(self.t_request_ns)
        };
        Reply::answer(self.cred, self.op, data, self.tick, t)
    }
}

/// A FIFO of at most `cap` requests, allocated once. Replies mostly come in request order, so
/// the request resolved is mostly the oldest: taking it out is O(1) here, where a `Vec` would
/// shift every later request (O(n) per reply, O(n²) per tick of n requests).
#[derive(Debug, Clone)]
struct Fifo {
    items: VecDeque<Pending>,
    cap: usize,
}

impl Fifo {
    fn with_capacity(cap: usize) -> Self {
        Self {
            items: VecDeque::with_capacity(cap),
            cap,
        }
    }

    /// Appends `p`; `false` (and nothing changes) when full: never reallocates.
    fn push(&mut self, p: Pending) -> bool {
        if self.items.len() >= self.cap {
            return false;
        }
        self.items.push_back(p);
        true
    }

    /// Removes the first request that `f` accepts, keeping the order of the rest.
    fn take_first(&mut self, f: impl Fn(&Pending) -> bool) -> Option<Pending> {
        let i = self.items.iter().position(f)?;
        self.items.remove(i)
    }
}

/// Fixed-capacity table of requests in flight, and of recently expired ones (whose replies, if
/// they still come, are late).
#[derive(Debug, Clone)]
pub struct Outstanding {
    pending: Fifo,
    expired: Fifo,
}

impl Outstanding {
    /// Room for `capacity` requests in flight.
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            pending: Fifo::with_capacity(capacity),
            expired: Fifo::with_capacity(capacity),
        }
    }

    /// Registers a request; `false` if the table is full (the caller counts a dropped request).
    pub fn track(&mut self, p: Pending) -> bool {
        self.pending.push(p)
    }

    /// Removes and returns the oldest pending request from `cred` that `matches` and was on the
    /// bus before the reply arrived (`end_pos <= fence`).
    pub fn resolve(
        &mut self,
        cred: Credential,
        fence: u64,
        matches: impl Fn(&Op) -> bool,
    ) -> Option<Pending> {
        self.pending
            .take_first(|p| p.cred == cred && p.end_pos <= fence && matches(&p.op))
    }

    /// A reply nobody pending can take: if it answers a request that expired (or one not yet
    /// on the bus when it arrived, i.e. an earlier one that expired), it is late. Consumes and
    /// returns the oldest such expired request.
    pub fn resolve_late(
        &mut self,
        cred: Credential,
        matches: impl Fn(&Op) -> bool,
    ) -> Option<Pending> {
        self.expired
            .take_first(|p| p.cred == cred && matches(&p.op))
    }

    /// Forgets the requests whose words lie at or after stream position `from` (never sent);
    /// returns how many.
    pub fn forget_from(&mut self, from: u64) -> u64 {
        let before = self.pending.items.len();
        self.pending.items.retain(|p| p.end_pos <= from);
        (before - self.pending.items.len()) as u64
    }

    /// Moves every request past its deadline into `out` as [`ReplyData::Missing`]; returns how
    /// many expired. Expired requests are remembered (oldest forgotten first) so that their
    /// late replies are recognised.
    pub fn expire(&mut self, now_ns: u64, out: &mut Bounded<Reply>) -> u64 {
        let mut n = 0;
        let Self { pending, expired } = self;
        pending.items.retain(|p| {
            if p.deadline_ns > now_ns {
                return true;
            }
            n += 1;
            let _ = out.push(p.reply(ReplyData::Missing { op: p.op }));
            if expired.items.len() >= expired.cap {
                expired.items.pop_front();
            }
            let _ = expired.push(*p);
            false
        });
        n
    }

    /// Answers every request in flight with `Missing` and forgets everything (the bus was
    /// lost); returns how many.
    pub fn drain_missing(&mut self, out: &mut Bounded<Reply>) -> u64 {
        let n = self.pending.items.len() as u64;
        for p in &self.pending.items {
            let _ = out.push(p.reply(ReplyData::Missing { op: p.op }));
        }
        self.clear();
        n
    }

    /// Requests in flight.
    pub fn len(&self) -> usize {
        self.pending.items.len()
    }

    /// Whether nothing is in flight.
    pub fn is_empty(&self) -> bool {
        self.pending.items.is_empty()
    }

    /// Forgets everything (e.g. after the bus was reset).
    pub fn clear(&mut self) {
        self.pending.items.clear();
        self.expired.items.clear();
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
            end_pos: tick,
        }
    }

    #[test]
    fn resolve_in_order_and_expire_the_rest() {
        let mut o = Outstanding::with_capacity(8);
        assert!(o.track(p(1, 1, 100)));
        assert!(o.track(p(2, 1, 100)));
        assert!(o.track(p(1, 2, 200)));
        assert!(o.track(p(3, 2, 300)));
        let r = o.resolve(Credential::id(1), u64::MAX, |_| true).unwrap();
        assert_eq!(r.tick, 1, "oldest first");
        assert_eq!(o.len(), 3);
        let mut out = Bounded::with_capacity(8);
        assert_eq!(o.expire(250, &mut out), 2);
        let expired: Vec<(u32, u64)> = out.as_slice().iter().map(|r| (r.cred.id, r.tick)).collect();
        assert_eq!(expired, [(2, 1), (1, 2)]);
        assert!(matches!(out.as_slice()[0].data, ReplyData::Missing { .. }));
        assert_eq!(o.len(), 1);
        assert_eq!(
            o.resolve(Credential::id(3), u64::MAX, |_| true)
                .unwrap()
                .tick,
            2
        );
        assert!(o.is_empty());
        assert!(o.resolve(Credential::id(3), u64::MAX, |_| true).is_none());
        // The expired ones make their late replies recognisable, once each.
        assert_eq!(
            o.resolve_late(Credential::id(2), |_| true).map(|p| p.tick),
            Some(1)
        );
        assert!(o.resolve_late(Credential::id(2), |_| true).is_none());
    }

    /// A reply is never matched to a request that was not on the bus before it arrived.
    #[test]
    fn the_fence_keeps_a_reply_from_answering_a_later_request() {
        let mut o = Outstanding::with_capacity(8);
        assert!(o.track(p(1, 5, 100)));
        assert!(o.resolve(Credential::id(1), 4, |_| true).is_none());
        assert_eq!(o.resolve(Credential::id(1), 5, |_| true).unwrap().tick, 5);
    }

    #[test]
    fn full_table_refuses() {
        let mut o = Outstanding::with_capacity(1);
        assert!(o.track(p(1, 1, 1)));
        assert!(!o.track(p(2, 1, 1)));
    }
}
