//! [`RtIpc`]: the iceoryx2 `ipc` service variant with an allocation-free per-sample path.
//!
//! iceoryx2 0.10's `ipc::Service` wraps every loaned sample's bookkeeping in an `Rc`
//! (`ArcThreadSafetyPolicy = SingleThreaded`), so each `loan_uninit()` calls the heap allocator:
//! one 48-byte allocation per published sample, on the executor's real-time path. `RtIpc` is the
//! same variant, byte-for-byte compatible on the wire (same shared memory, events, static configs,
//! so `ipc::Service` peers in any language connect to it), except that this process-local
//! reference counting comes from [`PooledRc`]: a pre-faulted, per-thread pool of fixed-size slots.
//! Taking and returning a slot is a free-list pop/push; no lock, no system call, no allocator.
//!
//! Large shared states (the ports' own, created once at set-up) do not fit a slot and fall back
//! to a heap box, which is harmless at set-up; [`heap_fallbacks`] counts them.

use core::cell::{Cell, RefCell};
use core::fmt::Debug;
use core::marker::PhantomData;
use core::mem::MaybeUninit;
use core::ops::Deref;
use core::ptr::NonNull;

use iceoryx2::service::internal::ServiceInternal;
use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use iceoryx2_cal::arc_sync_policy::{ArcSyncPolicy, ArcSyncPolicyCreationError, LockGuard};
use iceoryx2_cal::shm_allocator::bump_allocator::BumpAllocator;
use iceoryx2_cal::shm_allocator::pool_allocator::PoolAllocator;
use iceoryx2_cal::*;

/// The Conductor service variant: iceoryx2 `ipc` with pooled per-sample bookkeeping.
#[derive(Debug, Clone)]
pub struct RtIpc {}

impl iceoryx2::service::Service for RtIpc {
    type StaticStorage = static_storage::recommended::Ipc;
    type ConfigSerializer = serialize::recommended::Recommended;
    type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
        dynamic_storage::recommended::PersistentIpc<T>;
    type Bag = bag::recommended::Recommended;
    type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
        dynamic_storage::recommended::Ipc<T>;
    type ServiceNameHasher = hash::recommended::Recommended;
    type SharedMemory = shared_memory::recommended::Ipc<PoolAllocator>;
    type ResizableSharedMemory = resizable_shared_memory::recommended::Ipc<PoolAllocator>;
    type Connection = zero_copy_connection::recommended::Ipc;
    type Event = event::recommended::Ipc;
    type Monitoring = monitoring::recommended::Ipc;
    type Reactor = reactor::recommended::Ipc;
    type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> = PooledRc<T>;
    type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> =
        dynamic_storage::recommended::Ipc<KeyType>;
    type BlackboardPayload = shared_memory::recommended::Ipc<BumpAllocator>;
    type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
}

impl ServiceInternal<RtIpc> for RtIpc {}

/// Bytes per pool slot: fits iceoryx2's per-sample state (48 bytes) with room to spare.
const SLOT_BYTES: usize = 128;
/// Slot alignment.
const SLOT_ALIGN: usize = 16;
/// Slots per thread. Each outstanding loan holds one; a port holds at most its
/// `max_loaned_samples` (2 by default), so 512 covers hundreds of publishers in one thread.
const SLOTS: usize = 512;

#[repr(C, align(16))]
struct Slot([MaybeUninit<u8>; SLOT_BYTES]);

struct Pool {
    base: *mut Slot,
    free: Vec<u32>,
}

thread_local! {
    static POOL: RefCell<Option<Pool>> = const { RefCell::new(None) };
    static HEAP_FALLBACKS: Cell<u64> = const { Cell::new(0) };
}

/// Number of [`PooledRc`]s this thread put on the heap (too large for a slot, or the pool was
/// exhausted or not available). Large port states at set-up land here by design; on a real-time
/// thread the count must not grow after set-up.
pub fn heap_fallbacks() -> u64 {
    HEAP_FALLBACKS.with(Cell::get)
}

fn new_pool() -> Pool {
    let mut slots: Vec<Slot> = Vec::with_capacity(SLOTS);
    // Writing every slot pre-faults the pages, so the RT thread never takes a page fault here.
    slots.resize_with(SLOTS, || Slot([MaybeUninit::new(0); SLOT_BYTES]));
    // The slots live as long as the process: a thread may exit while a value it pooled is still
    // referenced from somewhere being torn down, and a leaked 64 KiB per thread is cheap.
    let base = Box::leak(slots.into_boxed_slice()).as_mut_ptr();
    Pool {
        base,
        free: (0..SLOTS as u32).rev().collect(),
    }
}

/// Creates this thread's pool now (allocating and pre-faulting it), so that the first sample
/// published from a real-time thread does not. Idempotent.
pub fn prepare_thread() {
    POOL.with(|p| {
        let mut p = p.borrow_mut();
        if p.is_none() {
            *p = Some(new_pool());
        }
    });
}

fn take_slot() -> Option<NonNull<Slot>> {
    POOL.try_with(|p| {
        let mut p = p.borrow_mut();
        let pool = p.get_or_insert_with(new_pool);
        let idx = pool.free.pop()?;
        // SAFETY: idx < SLOTS, the length of the allocation `base` points to.
        NonNull::new(unsafe { pool.base.add(idx as usize) })
    })
    .ok()
    .flatten()
}

fn return_slot(slot: NonNull<Slot>) {
    // If the thread-local is already gone (thread teardown), the slot is simply not reused.
    let _ = POOL.try_with(|p| {
        if let Some(pool) = p.borrow_mut().as_mut() {
            // SAFETY: `slot` came from this thread's pool (PooledRc is !Send), so both pointers
            // are into the same allocation.
            let idx = unsafe { slot.as_ptr().offset_from(pool.base) } as u32;
            // Never exceeds SLOTS entries, so the pre-sized Vec does not reallocate.
            pool.free.push(idx);
        }
    });
}

struct Inner<T> {
    strong: Cell<usize>,
    pooled: bool,
    value: T,
}

/// A single-threaded reference-counted box whose storage comes from a per-thread pool.
/// Semantically `Rc<T>`; `!Send` like it.
pub struct PooledRc<T> {
    ptr: NonNull<Inner<T>>,
    _owns: PhantomData<Inner<T>>,
    _not_send: PhantomData<*const ()>,
}

impl<T> PooledRc<T> {
    fn inner(&self) -> &Inner<T> {
        // SAFETY: `ptr` points to a live Inner<T> while any PooledRc to it exists (refcount > 0).
        unsafe { self.ptr.as_ref() }
    }
}

impl<T: Debug> Debug for PooledRc<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.inner().value.fmt(f)
    }
}

impl<T> Clone for PooledRc<T> {
    fn clone(&self) -> Self {
        let s = &self.inner().strong;
        s.set(s.get() + 1);
        Self {
            ptr: self.ptr,
            _owns: PhantomData,
            _not_send: PhantomData,
        }
    }
}

impl<T> Drop for PooledRc<T> {
    fn drop(&mut self) {
        let s = &self.inner().strong;
        let n = s.get() - 1;
        s.set(n);
        if n > 0 {
            return;
        }
        if self.inner().pooled {
            // SAFETY: this was the last reference; the value is dropped exactly once and the slot
            // is handed back only afterwards.
            unsafe { core::ptr::drop_in_place(self.ptr.as_ptr()) };
            return_slot(self.ptr.cast());
        } else {
            // SAFETY: non-pooled values were created by Box::into_raw in `new`; last reference.
            drop(unsafe { Box::from_raw(self.ptr.as_ptr()) });
        }
    }
}

/// Borrow of a [`PooledRc`]'s value.
pub struct Guard<'parent, T>(&'parent T);

impl<T> Deref for Guard<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        self.0
    }
}

impl<'parent, T: Send + Abandonable> LockGuard<'parent, T> for Guard<'parent, T> {}

impl<T: Send + Debug + Abandonable> Abandonable for PooledRc<T> {
    /// Gives up this reference without running destructors (the value is abandoned with the
    /// last reference and its slot or box leaked), as iceoryx2 does on a crashed owner.
    ///
    /// # Safety
    ///
    /// `this` points to a live `PooledRc` on this thread that nobody uses, clones or drops
    /// afterwards (the contract of [`Abandonable::abandon_in_place`]).
    unsafe fn abandon_in_place(this: NonNull<Self>) {
        // SAFETY: the caller guarantees `this` points to a live PooledRc.
        let this = unsafe { this.as_ref() };
        let s = &this.inner().strong;
        if s.get() == 1 {
            // Last reference: abandon the value and leak its storage, as SingleThreaded does.
            // SAFETY: we hold the only reference; the value is live and never touched again.
            unsafe { T::abandon_in_place(NonNull::from(&mut (*this.ptr.as_ptr()).value)) };
        } else {
            s.set(s.get() - 1);
        }
    }
}

impl<T: Send + Debug + Abandonable> ArcSyncPolicy<T> for PooledRc<T> {
    type LockGuard<'parent>
        = Guard<'parent, T>
    where
        Self: 'parent,
        T: 'parent;

    fn new(value: T) -> Result<Self, ArcSyncPolicyCreationError> {
        let inner = Inner {
            strong: Cell::new(1),
            pooled: true,
            value,
        };
        let fits = core::mem::size_of::<Inner<T>>() <= SLOT_BYTES
            && core::mem::align_of::<Inner<T>>() <= SLOT_ALIGN;
        let ptr = match fits.then(take_slot).flatten() {
            Some(slot) => {
                let p = slot.cast::<Inner<T>>();
                // SAFETY: the slot is unused, large and aligned enough for Inner<T> (checked).
                unsafe { p.as_ptr().write(inner) };
                p
            }
            None => {
                let _ = HEAP_FALLBACKS.try_with(|c| c.set(c.get() + 1));
                let boxed = Box::new(Inner {
                    pooled: false,
                    ..inner
                });
                // SAFETY: Box::into_raw never returns null.
                unsafe { NonNull::new_unchecked(Box::into_raw(boxed)) }
            }
        };
        Ok(Self {
            ptr,
            _owns: PhantomData,
            _not_send: PhantomData,
        })
    }

    fn lock(&self) -> Self::LockGuard<'_> {
        Guard(&self.inner().value)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::rc::Rc;

    #[derive(Debug)]
    struct Probe(Rc<Cell<u32>>);
    impl Drop for Probe {
        fn drop(&mut self) {
            self.0.set(self.0.get() + 1);
        }
    }
    impl Abandonable for Probe {
        unsafe fn abandon_in_place(_: NonNull<Self>) {}
    }
    // SAFETY: (test only) the probe never leaves its thread; Send is required by the trait bound.
    unsafe impl Send for Probe {}

    #[test]
    fn drops_once_after_last_clone_and_reuses_slots() {
        prepare_thread();
        let drops = Rc::new(Cell::new(0));
        let before = heap_fallbacks();
        for i in 0..(SLOTS as u32 * 3) {
            let a = PooledRc::new(Probe(drops.clone())).unwrap();
            let b = a.clone();
            assert!(Rc::ptr_eq(&a.lock().deref().0, &drops));
            drop(a);
            assert_eq!(drops.get(), i, "value dropped while a clone lives");
            drop(b);
            assert_eq!(drops.get(), i + 1);
        }
        assert_eq!(drops.get(), SLOTS as u32 * 3);
        // Slots were recycled: three times the pool size without touching the heap.
        assert_eq!(heap_fallbacks(), before);
    }

    #[test]
    fn oversized_values_fall_back_to_the_heap() {
        #[derive(Debug)]
        struct Big([u8; 1024]);
        impl Abandonable for Big {
            unsafe fn abandon_in_place(_: NonNull<Self>) {}
        }
        let before = heap_fallbacks();
        let a = PooledRc::new(Big([7; 1024])).unwrap();
        assert_eq!(a.lock().deref().0[1023], 7);
        assert!(heap_fallbacks() > before);
    }

    #[test]
    fn exhausted_pool_falls_back_instead_of_failing() {
        let drops = Rc::new(Cell::new(0));
        let held: Vec<_> = (0..SLOTS + 8)
            .map(|_| PooledRc::new(Probe(drops.clone())).unwrap())
            .collect();
        drop(held);
        assert_eq!(drops.get(), SLOTS as u32 + 8);
    }
}
