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
use std::sync::{Arc, Mutex as SyncMutex};
use std::time::{Duration, Instant};
use tokio::sync::Mutex;
use tokio::task::JoinHandle;

/// How long a worker's or a tracker's loop may go without saying it
/// progressed before its leases are left to expire.
pub const STALL: Duration = Duration::from_secs(30);

/// One lease held.
struct Lease {
    /// What a renewal writes (the holder's name).
    value: Vec<u8>,
    revision: u64,
    renewed: Instant,
}

/// What the keeper holds, shared with its task.
#[derive(Default)]
struct Held {
    leases: BTreeMap<String, Lease>,
    /// Keys whose lease was found gone or another's, not yet told.
    lost: Vec<String>,
    /// The holder's last heartbeat (bucket `workers`), put again each round.
    beat: Option<(String, Vec<u8>)>,
}

/// Renews leases in the `leases` bucket (and a heartbeat) from a task of
/// its own until dropped.
pub struct Keeper {
    held: Arc<Mutex<Held>>,
    progress: Arc<SyncMutex<Instant>>,
    task: JoinHandle<()>,
}

impl Keeper {
    /// Starts keeping leases on `site` (in the current Tokio runtime) while
    /// the work says it progressed ([`Keeper::alive`]) within `stall`, or
    /// within the lease time when that is longer.
    pub fn start(site: &Site, stall: Duration) -> Keeper {
        let held = Arc::new(Mutex::new(Held::default()));
        let progress = Arc::new(SyncMutex::new(Instant::now()));
        let task = tokio::spawn(keep(site.clone(), held.clone(), progress.clone(), stall));
        Keeper {
            held,
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

    /// The leases lost since last asked (they are no longer kept).
    pub async fn lost(&self) -> Vec<String> {
        std::mem::take(&mut self.held.lock().await.lost)
    }

    /// Puts `value` as `key` in the `workers` bucket now and again each
    /// round, so the holder stays among the live while a frame is long.
    pub async fn beat(&self, site: &Site, key: String, value: Vec<u8>) -> crate::Result<()> {
        // Put under the lock, so that no round puts an older one after it.
        let mut held = self.held.lock().await;
        site.workers
            .put(&key, value.clone().into())
            .await
            .map_err(|e| crate::ClusterError::bus("cannot send a heartbeat", e))?;
        held.beat = Some((key, value));
        Ok(())
    }

    /// Stops putting the heartbeat `key` and deletes it (the holder is
    /// leaving), so that no round puts it back.
    pub async fn end_beat(&self, site: &Site, key: &str) {
        let mut held = self.held.lock().await;
        held.beat = None;
        let _ = site.workers.delete(key).await;
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
    progress: Arc<SyncMutex<Instant>>,
    stall: Duration,
) {
    loop {
        tokio::time::sleep(site.lease_ttl / 4).await;
        // Another worker's --lease-seconds may have changed it; a failed
        // read keeps the last.
        let _ = site.refresh_lease().await;
        let ttl = site.lease_ttl;
        let stalled = progress.lock().expect("progress lock").elapsed() >= stall.max(ttl);
        let mut h = held.lock().await;
        let h = &mut *h;
        let mut lost = Vec::new();
        for (key, lease) in &mut h.leases {
            if stalled {
                if lease.renewed.elapsed() >= ttl {
                    lost.push(key.clone());
                }
                continue;
            }
            match site
                .leases
                .update(key, lease.value.clone().into(), lease.revision)
                .await
            {
                Ok(r) => {
                    lease.revision = r;
                    lease.renewed = Instant::now();
                }
                Err(e) if e.kind() == kv::UpdateErrorKind::WrongLastRevision => {
                    lost.push(key.clone())
                }
                // The bus may be back before the lease runs out.
                Err(_) if lease.renewed.elapsed() >= ttl => lost.push(key.clone()),
                Err(_) => {}
            }
        }
        for key in lost {
            h.leases.remove(&key);
            h.lost.push(key);
        }
        if let (false, Some((key, value))) = (stalled, &h.beat) {
            let _ = site.workers.put(key, value.clone().into()).await;
        }
    }
}
