//! Leases kept alive by a task of their own, apart from the work they
//! guard.
//!
//! A worker that renewed its leases only between frames lost them whenever
//! one frame took longer than the lease time (a loaded machine, a large
//! checkpoint to load): another process took the shard or the sensor over,
//! lost it the same way, and on a slow enough machine the two handed the
//! work back and forth without either finishing it. As Kafka separates a
//! consumer's heartbeat from its processing, the keeper renews every
//! quarter of the lease time whatever the work is doing, so a lease says
//! the process is alive; and it stops renewing when the work has made no
//! progress for a while ([`STALL`] for the workers), so a process stuck for
//! good still gives its leases up.

use crate::site::Site;
use async_nats::jetstream::kv;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex as SyncMutex};
use std::time::{Duration, Instant};
use tokio::sync::Mutex;
use tokio::task::JoinHandle;

/// How long a worker's or a tracker's loop may go without saying it
/// progressed before its leases are left to expire.
pub const STALL: Duration = Duration::from_secs(30);

/// How long a stopping worker or tracker may take to give its leases back
/// (a worker checkpoints its shards first). With the bus gone each request
/// would wait out its timeout, one after another, for minutes; past this
/// the process exits and its leases expire instead.
pub const HANDOVER: Duration = Duration::from_secs(20);

/// One lease held.
struct Lease {
    /// What a renewal writes: the holder's name, which no other process
    /// has, so that a lease read back tells whose it is.
    value: Vec<u8>,
    revision: u64,
    renewed: Instant,
}

/// What the keeper holds, shared with its task.
#[derive(Default)]
struct Held {
    leases: BTreeMap<String, Lease>,
    /// Keys whose lease was found another's, or not renewed within the
    /// lease time (the bus unreachable, the work stalled), not yet told.
    lost: Vec<String>,
    /// The holder's last heartbeat (bucket `workers`), put again each round.
    beat: Option<(String, Vec<u8>)>,
}

/// Renews leases in the `leases` bucket (and a heartbeat) from a task of
/// its own until dropped.
pub struct Keeper {
    /// The site leases are given back and heartbeats put on.
    site: Site,
    held: Arc<Mutex<Held>>,
    /// Set with `Held::lost`, so that asking after every frame takes no
    /// lock (a round holds it while renewing).
    any_lost: Arc<AtomicBool>,
    progress: Arc<SyncMutex<Instant>>,
    task: JoinHandle<()>,
}

impl Keeper {
    /// Starts keeping leases on `site` (in the current Tokio runtime) while
    /// the work says it progressed ([`Keeper::alive`]) within `stall`, or
    /// within the lease time when that is longer.
    pub fn start(site: &Site, stall: Duration) -> Keeper {
        let held = Arc::new(Mutex::new(Held::default()));
        let any_lost = Arc::new(AtomicBool::new(false));
        let progress = Arc::new(SyncMutex::new(Instant::now()));
        let task = tokio::spawn(keep(
            site.clone(),
            held.clone(),
            any_lost.clone(),
            progress.clone(),
            stall,
        ));
        Keeper {
            site: site.clone(),
            held,
            any_lost,
            progress,
            task,
        }
    }

    /// The work progressed: its leases are worth keeping.
    pub fn alive(&self) {
        *self.progress.lock().expect("progress lock") = Instant::now();
    }

    /// Keeps the lease `key`, just created or updated to `revision` with `value`.
    pub async fn hold(&self, key: String, value: Vec<u8>, revision: u64) {
        let lease = Lease {
            value,
            revision,
            renewed: Instant::now(),
        };
        self.held.lock().await.leases.insert(key, lease);
    }

    /// Stops keeping `key`: its revision, to delete it with, if still held.
    pub async fn release(&self, key: &str) -> Option<u64> {
        self.held
            .lock()
            .await
            .leases
            .remove(key)
            .map(|l| l.revision)
    }

    /// Stops keeping `key` and deletes it, so that another may take it
    /// now rather than when it expires.
    pub async fn give_back(&self, key: &str) {
        if let Some(revision) = self.release(key).await {
            let _ = self
                .site
                .leases
                .delete_expect_revision(key, Some(revision))
                .await;
        }
    }

    /// The leases lost since last asked (they are no longer kept).
    pub async fn lost(&self) -> Vec<String> {
        if !self.any_lost.swap(false, Ordering::AcqRel) {
            return Vec::new();
        }
        std::mem::take(&mut self.held.lock().await.lost)
    }

    /// Puts `value` as `key` in the `workers` bucket now and again each
    /// round, so the holder stays among the live while a frame is long.
    pub async fn beat(&self, key: String, value: Vec<u8>) -> crate::Result<()> {
        // Put under the lock, so that no round puts an older one after it.
        let mut held = self.held.lock().await;
        self.site
            .workers
            .put(&key, value.clone().into())
            .await
            .map_err(|e| crate::ClusterError::bus("cannot send a heartbeat", e))?;
        held.beat = Some((key, value));
        Ok(())
    }

    /// Stops putting the heartbeat `key` and deletes it (the holder is
    /// leaving), so that no round puts it back.
    pub async fn end_beat(&self, key: &str) {
        let mut held = self.held.lock().await;
        held.beat = None;
        let _ = self.site.workers.delete(key).await;
    }
}

impl Drop for Keeper {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// The keeper's task: a round every quarter of the lease time.
async fn keep(
    mut site: Site,
    held: Arc<Mutex<Held>>,
    any_lost: Arc<AtomicBool>,
    progress: Arc<SyncMutex<Instant>>,
    stall: Duration,
) {
    loop {
        // Read before sleeping: another process's --lease-seconds may have
        // shortened it since this one connected. A failed read keeps the last.
        let _ = site.refresh_lease().await;
        let ttl = site.lease_ttl;
        tokio::time::sleep(ttl / 4).await;
        let stalled = progress.lock().expect("progress lock").elapsed() >= stall.max(ttl);
        let mut h = held.lock().await;
        let h = &mut *h;
        // All at once, each given at most a round: renewing many shards one
        // after another on a slow bus could outlast the lease, and the lock
        // (which keeps a release from racing a renewal) is held meanwhile.
        let renewals = h.leases.iter().filter(|_| !stalled).map(|(key, lease)| {
            let renewal = renew(&site.leases, key, lease);
            async move { (key.clone(), tokio::time::timeout(ttl / 4, renewal).await) }
        });
        let renewed = futures_util::future::join_all(renewals).await;
        let mut lost = Vec::new();
        for (key, outcome) in renewed {
            let lease = h.leases.get_mut(&key).expect("held while renewing");
            match outcome {
                Ok(Renewal::Renewed(r)) => {
                    lease.revision = r;
                    lease.renewed = Instant::now();
                }
                Ok(Renewal::Taken) => lost.push(key),
                // The bus may be back before the lease runs out.
                _ if lease.renewed.elapsed() >= ttl => lost.push(key),
                _ => {}
            }
        }
        if stalled {
            lost.extend(
                h.leases
                    .iter()
                    .filter(|(_, l)| l.renewed.elapsed() >= ttl)
                    .map(|(k, _)| k.clone()),
            );
        }
        for key in lost {
            h.leases.remove(&key);
            h.lost.push(key);
            // Under the lock, after the push: `lost()` drains under it too.
            any_lost.store(true, Ordering::Release);
        }
        if let (false, Some((key, value))) = (stalled, &h.beat) {
            let _ =
                tokio::time::timeout(ttl / 4, site.workers.put(key, value.clone().into())).await;
        }
    }
}

/// What renewing one lease came to.
enum Renewal {
    /// Renewed: the lease's new revision.
    Renewed(u64),
    /// The lease is another's now, or gone.
    Taken,
    /// Refused for another reason, or not answered (a renewal the bus
    /// does not answer is usually cut short by the round's time limit).
    Failed,
}

/// Renews `lease`, stored as `key` in `leases`.
///
/// A renewal refused for a wrong revision is not yet a lost lease: one
/// this keeper stopped waiting for (its reply lost, or the request sent
/// only once the connection came back after an outage) may have been
/// applied after all, moving the revision on unseen. So the lease is read
/// back, and while it still holds this holder's value it is renewed again
/// at the revision read (another such renewal may land first, up to
/// [`RENEW_TRIES`] times; the round's time limit bounds them too).
async fn renew(leases: &kv::Store, key: &str, lease: &Lease) -> Renewal {
    let value = bytes::Bytes::from(lease.value.clone());
    let mut revision = lease.revision;
    for _ in 0..RENEW_TRIES {
        match leases.update(key, value.clone(), revision).await {
            Ok(r) => return Renewal::Renewed(r),
            Err(e) if e.kind() != kv::UpdateErrorKind::WrongLastRevision => return Renewal::Failed,
            Err(_) => {}
        }
        revision = match leases.entry(key).await {
            Ok(Some(e)) if e.operation == kv::Operation::Put && e.value == value => e.revision,
            Ok(_) => return Renewal::Taken,
            Err(_) => return Renewal::Failed,
        };
    }
    Renewal::Failed
}

/// Renewals [`renew`] tries in one round while the lease read back is
/// still this holder's.
const RENEW_TRIES: usize = 3;
