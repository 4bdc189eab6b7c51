//! A fusion worker (`depthmesh cluster worker`): owns some of the site's
//! shards, fuses into them every posed frame of the stream in the stream's
//! order, checkpoints them, and hands them over.
//!
//! Each owned shard has its own position in the stream. The worker reads
//! the message at the smallest position and fuses it into the shards at
//! that position only, so a shard taken over from a checkpoint behind the
//! others catches up by itself, frame by frame, until it reaches them; a
//! frame is read once however many shards it feeds. A checkpoint commits
//! a shard's blocks with the position they include; a shard is taken over
//! from its last checkpoint and continues after it, so every frame is fused
//! into every shard exactly once, whoever owned it when.
//!
//! Its leases are renewed by a [`Keeper`], apart from the fusing, so a long
//! frame does not lose them; a lease the keeper reports lost is given up
//! before the next frame (another worker may have it). Every quarter of the
//! lease time the worker says it is alive and balances: it takes unowned
//! shards while it has fewer than its share (all shards over the live
//! workers, rounded up), and gives those above it back, checkpointed.

use crate::checkpoint::{
    commit, encode_segment, load_shard, read_manifest, shard_key, write_segment, Manifest,
};
use crate::error::{ClusterError, Result};
use crate::fuse::{FuseTimes, Fused, Fuser, StreamReader};
use crate::keeper::{Keeper, HANDOVER, STALL};
use crate::outage::Outage;
use crate::site::{live_entries, Site};
use depthmesh::tsdf::regions::Regions;
use glam::IVec3;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// A shard's checkpoints are rewritten whole (the older segments deleted)
/// once it has this many: loading a shard then reads at most this many.
const MAX_SEGMENTS: usize = 8;

/// Checkpoints of a shard tried without an answer that are remembered.
const MAX_UNANSWERED: usize = 8;

/// How a worker runs.
#[derive(Clone, Debug)]
pub struct WorkerOptions {
    /// Its name, unique on the site.
    pub id: String,
    /// A shard is checkpointed after this many frames fused into it (and
    /// whenever the worker has caught up with the stream).
    pub checkpoint_every: u64,
}

/// One live worker's figures, as its heartbeat says them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Heartbeat {
    /// The worker.
    pub id: String,
    /// Its shards and each one's next stream position.
    pub shards: Vec<(u32, u64)>,
    /// Messages read and fused per second since the last heartbeat.
    pub frames_per_second: f64,
    /// Messages read and fused since it started.
    pub frames: u64,
    /// Checkpoints committed since it started.
    pub checkpoints: u64,
    /// Seconds spent decoding and fusing since it started.
    pub fuse_seconds: FuseTimes,
    /// Seconds spent writing checkpoints since it started.
    pub checkpoint_seconds: f64,
    /// Seconds since the Unix epoch when its figures were taken.
    pub at: f64,
}

/// A shard this worker owns.
struct Owned {
    shard: u32,
    /// The next stream position to fuse.
    next: u64,
    /// Posed frames fused into it and frames rejected, all told.
    frames: u64,
    rejected: u64,
    /// The last committed checkpoint and its revision.
    manifest: Manifest,
    manifest_revision: Option<u64>,
    /// The volume's frame count when that checkpoint was taken.
    saved_at: u32,
    /// Checkpoints tried since then whose commit got no answer: the bus
    /// may have applied them (see [`Worker::commit_checkpoint`]).
    unanswered: Vec<Manifest>,
}

impl Owned {
    fn unsaved(&self) -> bool {
        self.next - 1 > self.manifest.seq
    }

    fn frames_since_save(&self) -> u64 {
        self.frames + self.rejected - self.manifest.frames - self.manifest.rejected
    }
}

/// The worker's state between messages.
struct Worker<'a> {
    site: Site,
    options: &'a WorkerOptions,
    regions: Regions,
    fuser: Fuser,
    owned: Vec<Owned>,
    keeper: Keeper,
    /// Messages read since start and at the last heartbeat, checkpoints made.
    frames: u64,
    frames_at_beat: u64,
    beat_at: Instant,
    checkpoints: u64,
    checkpoint_seconds: f64,
}

/// Where the loop stands between frames.
struct Cursor {
    reader: StreamReader,
    /// The stream's last message as last asked.
    last: u64,
    next_beat: Instant,
}

/// Runs a worker on `site` until `stop` is set; then checkpoints its
/// shards and gives them back.
pub async fn run(site: &Site, options: &WorkerOptions, stop: &AtomicBool) -> Result<()> {
    let config = site.required_config().await?;
    let mut w = Worker {
        site: site.clone(),
        options,
        regions: config.regions,
        fuser: Fuser::new(config)?,
        owned: Vec::new(),
        keeper: Keeper::start(site, STALL),
        frames: 0,
        frames_at_beat: 0,
        beat_at: Instant::now(),
        checkpoints: 0,
        checkpoint_seconds: 0.0,
    };
    let mut cursor = Cursor {
        reader: StreamReader::new(site),
        last: site.last_seq().await?,
        next_beat: Instant::now(),
    };
    let mut outage = Outage::default();
    let who = format!("worker {}", options.id);
    // A failed turn leaves nothing half done that the next one repeats: a
    // frame counts as fused once it is in the volume, and a checkpoint or a
    // shard is written or taken again whole.
    let worked: Result<()> = loop {
        if stop.load(Ordering::Relaxed) {
            break Ok(());
        }
        let turn = w.step(&mut cursor).await;
        if let Err(e) = outage.after(&who, turn).await {
            break Err(e);
        }
    };
    // Told to stop, a worker whose last request failed (the bus going
    // down with the machine) still tries to hand its shards over.
    if worked.is_err() && !stop.load(Ordering::Relaxed) {
        return worked;
    }
    // Past the limit nothing is lost: the shards' leases expire and their
    // next owners resume from the last checkpoints.
    tokio::time::timeout(HANDOVER, w.release_all())
        .await
        .unwrap_or_else(|_| {
            Err(ClusterError::Bus(format!(
                "could not hand the shards over within {} s; they are taken over \
                 from their last checkpoints once their leases expire",
                HANDOVER.as_secs()
            )))
        })
}

impl Worker<'_> {
    /// One turn of the loop: the heartbeat when due, then the next frame
    /// (or the checkpoints of a worker that has caught up).
    async fn step(&mut self, c: &mut Cursor) -> Result<()> {
        self.keeper.alive();
        self.drop_lost().await;
        let beat_every = self.site.lease_ttl / 4;
        if Instant::now() >= c.next_beat {
            self.heartbeat().await?;
            c.next_beat = Instant::now() + beat_every;
        }
        let Some(at) = self.owned.iter().map(|o| o.next).min() else {
            tokio::time::sleep(beat_every.min(Duration::from_millis(200))).await;
            return Ok(());
        };
        if at > c.last {
            c.last = self.site.last_seq().await?;
            if at > c.last {
                self.save_unsaved().await?;
                tokio::time::sleep(Duration::from_millis(20)).await;
                return Ok(());
            }
        }
        let msg = c.reader.get(at, c.last).await?;
        self.fuse_at(at, msg).await
    }

    /// Fuses message `at` into the shards waiting for it.
    async fn fuse_at(
        &mut self,
        at: u64,
        msg: Option<async_nats::jetstream::message::StreamMessage>,
    ) -> Result<()> {
        let mut members = vec![false; self.regions.shards as usize];
        for o in self.owned.iter().filter(|o| o.next == at) {
            members[o.shard as usize] = true;
        }
        let regions = self.regions;
        let keep = |k: IVec3| members[regions.shard_of(k) as usize];
        let fused = match &msg {
            Some(m) => self.fuser.fuse(&self.site, m, keep).await?,
            None => Fused::Skipped,
        };
        if let Fused::Rejected(why) = &fused {
            eprintln!("worker {}: message {at} rejected: {why}", self.options.id);
        }
        self.frames += 1;
        let mut due = Vec::new();
        for o in self.owned.iter_mut().filter(|o| o.next == at) {
            o.next = at + 1;
            match fused {
                Fused::Frame => o.frames += 1,
                Fused::Rejected(_) => o.rejected += 1,
                Fused::Skipped => {}
            }
            if o.frames_since_save() >= self.options.checkpoint_every {
                due.push(o.shard);
            }
        }
        for shard in due {
            self.checkpoint(shard).await?;
        }
        Ok(())
    }

    /// Checkpoints every shard with frames not yet committed.
    async fn save_unsaved(&mut self) -> Result<()> {
        let unsaved: Vec<u32> = self
            .owned
            .iter()
            .filter(|o| o.unsaved())
            .map(|o| o.shard)
            .collect();
        for shard in unsaved {
            self.checkpoint(shard).await?;
        }
        Ok(())
    }

    /// The keys of the blocks of `shard` this worker holds.
    fn shard_blocks(&self, shard: u32) -> Vec<IVec3> {
        let r = self.regions;
        self.fuser
            .volume
            .blocks()
            .iter()
            .map(|b| b.key)
            .filter(|&k| r.shard_of(k) == shard)
            .collect()
    }

    /// Commits `shard`'s changes since its last checkpoint; if another
    /// worker committed it meanwhile, the shard is given up.
    async fn checkpoint(&mut self, shard: u32) -> Result<()> {
        let start = Instant::now();
        let done = self.commit_checkpoint(shard).await;
        self.checkpoint_seconds += start.elapsed().as_secs_f64();
        // Many checkpoints in a row are progress too, for the keeper.
        self.keeper.alive();
        done
    }

    async fn commit_checkpoint(&mut self, shard: u32) -> Result<()> {
        let Some(i) = self.owned.iter().position(|o| o.shard == shard) else {
            return Ok(());
        };
        let o = &self.owned[i];
        let full = o.manifest.segments.len() >= MAX_SEGMENTS;
        let keys: Vec<IVec3> = if full {
            self.shard_blocks(shard)
        } else {
            let r = self.regions;
            let mut k = self.fuser.volume.changed_after(o.saved_at);
            k.retain(|&k| r.shard_of(k) == shard);
            k
        };
        let saved_at = self.fuser.volume.frames();
        let volume = &self.fuser.volume;
        let bytes = tokio::task::block_in_place(|| {
            encode_segment(keys.iter().filter_map(|&k| volume.block(k)))
        });
        let seq = o.next - 1;
        let name = format!("shard-{shard}/{seq:012}-{}", self.options.id);
        write_segment(&self.site, &name, &bytes).await?;
        let mut manifest = Manifest {
            seq,
            frames: o.frames,
            rejected: o.rejected,
            segments: if full {
                vec![name.clone()]
            } else {
                let mut s = o.manifest.segments.clone();
                s.push(name.clone());
                s
            },
            // A whole shard's keys are its blocks already.
            blocks: if full {
                keys.len()
            } else {
                self.shard_blocks(shard).len()
            } as u64,
            segment_bytes: bytes.len() as u64,
            writer: self.options.id.clone(),
        };
        if !full {
            manifest.segment_bytes += o.manifest.segment_bytes;
        }
        let base = o.manifest_revision;
        // Kept until the bus answers: a failed request may yet have been
        // applied (its reply lost, or the request sent only once the bus
        // was back).
        let unanswered = &mut self.owned[i].unanswered;
        if !unanswered.contains(&manifest) {
            // Bounded: a try forgotten here only costs the shard, at worst,
            // a hand-over if the bus did apply it.
            if unanswered.len() == MAX_UNANSWERED {
                unanswered.remove(0);
            }
            unanswered.push(manifest.clone());
        }
        let revision = match commit(&self.site, shard, &manifest, base).await? {
            Some(revision) => revision,
            None => {
                let stored = read_manifest(&self.site, shard).await?;
                match self.commit_over_own(shard, i, &manifest, &stored).await? {
                    Some(revision) => revision,
                    None => {
                        self.give_up(shard, &name, stored.map(|(m, _)| m)).await;
                        return Ok(());
                    }
                }
            }
        };
        let o = &mut self.owned[i];
        let tried = std::mem::take(&mut o.unanswered);
        let old = std::mem::replace(&mut o.manifest, manifest);
        o.manifest_revision = Some(revision);
        o.saved_at = saved_at;
        self.checkpoints += 1;
        // Segments no longer named: the old ones after a full rewrite, and
        // those of checkpoints tried without an answer and superseded. A
        // segment left behind wastes space, nothing more.
        let named = &self.owned[i].manifest.segments;
        let mut unnamed: Vec<String> = tried
            .into_iter()
            .flat_map(|m| m.segments)
            .chain(if full { old.segments } else { Vec::new() })
            .filter(|s| !named.contains(s))
            .collect();
        unnamed.sort();
        unnamed.dedup();
        for name in unnamed {
            let _ = self.site.checkpoints.delete(&name).await;
        }
        Ok(())
    }

    /// After the commit of `manifest` to `shard` (owned at `i`) was
    /// refused, `stored` being the manifest read back: its revision if
    /// that is this one, or it is
    /// committed on top of the stored one if that is a checkpoint this
    /// worker tried and heard nothing back from (the commit that moved the
    /// shard on was its own); `None` when another worker's commit did, or
    /// when the shard's lease is no longer this worker's (another may have
    /// taken the shard on from that very checkpoint). Giving the shard up
    /// for its own commit left it unfused for a lease time.
    async fn commit_over_own(
        &mut self,
        shard: u32,
        i: usize,
        manifest: &Manifest,
        stored: &Option<(Manifest, u64)>,
    ) -> Result<Option<u64>> {
        let Some((stored, revision)) = stored else {
            return Ok(None);
        };
        let same = stored == manifest;
        if !(same || self.owned[i].unanswered.contains(stored)) || !self.holds_lease(shard).await? {
            return Ok(None);
        }
        if same {
            return Ok(Some(*revision));
        }
        commit(&self.site, shard, manifest, Some(*revision)).await
    }

    /// Whether `shard`'s lease still names this worker.
    async fn holds_lease(&self, shard: u32) -> Result<bool> {
        let value = self
            .site
            .leases
            .get(shard_key(shard))
            .await
            .map_err(|e| ClusterError::bus("cannot read a lease", e))?;
        Ok(value.is_some_and(|v| *v == *self.options.id.as_bytes()))
    }

    /// Gives `shard` up after its commit of segment `name` was refused for
    /// another's: `stored` is the manifest read back. The segment goes only
    /// if that manifest does not name it (another worker may have taken
    /// the shard on from a commit of this one that named it).
    async fn give_up(&mut self, shard: u32, name: &str, stored: Option<Manifest>) {
        eprintln!(
            "worker {}: shard {shard} was committed since this worker's last \
             checkpoint of it; giving it up",
            self.options.id
        );
        if !stored.is_some_and(|m| m.segments.iter().any(|s| s == name)) {
            let _ = self.site.checkpoints.delete(name).await;
        }
        self.forget(shard).await;
    }

    /// Drops `shard` and its blocks without saving anything, and stops
    /// renewing its lease.
    async fn forget(&mut self, shard: u32) {
        self.keeper.release(&shard_key(shard)).await;
        let keys = self.shard_blocks(shard);
        self.fuser.volume.remove_blocks(&keys);
        self.owned.retain(|o| o.shard != shard);
    }

    /// Gives up, at once, the shards whose leases the keeper found lost:
    /// another worker may have them.
    async fn drop_lost(&mut self) {
        for key in self.keeper.lost().await {
            if let Some(o) = self.owned.iter().find(|o| shard_key(o.shard) == key) {
                let shard = o.shard;
                eprintln!("worker {}: lease of shard {shard} lost", self.options.id);
                self.forget(shard).await;
            }
        }
    }

    /// Says this worker is alive, balances shards.
    async fn heartbeat(&mut self) -> Result<()> {
        self.site.refresh_lease().await?;
        let now = Instant::now();
        let seconds = now.duration_since(self.beat_at).as_secs_f64().max(1e-3);
        let frames_per_second = (self.frames - self.frames_at_beat) as f64 / seconds;
        self.frames_at_beat = self.frames;
        self.beat_at = now;
        // Said before balancing, so a new worker counts itself among the
        // live ones; said again after, so the status shows its new shards.
        self.say_alive(frames_per_second).await?;
        let before: Vec<u32> = self.owned.iter().map(|o| o.shard).collect();
        self.balance().await?;
        if self.owned.iter().map(|o| o.shard).ne(before) {
            self.say_alive(frames_per_second).await?;
        }
        Ok(())
    }

    /// Puts this worker's heartbeat.
    async fn say_alive(&self, frames_per_second: f64) -> Result<()> {
        let beat = Heartbeat {
            id: self.options.id.clone(),
            shards: self.owned.iter().map(|o| (o.shard, o.next)).collect(),
            frames_per_second,
            frames: self.frames,
            checkpoints: self.checkpoints,
            fuse_seconds: self.fuser.times,
            checkpoint_seconds: self.checkpoint_seconds,
            at: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
        };
        let bytes = serde_json::to_vec(&beat).expect("heartbeat serialises");
        self.keeper.beat(self.options.id.clone(), bytes).await
    }

    /// Takes free shards up to this worker's share, or gives one back above it.
    async fn balance(&mut self) -> Result<()> {
        let live = self.live_workers().await?.max(1);
        let shards = self.regions.shards;
        let share = shards.div_ceil(live) as usize;
        if self.owned.len() > share {
            let extra: Vec<u32> = self.owned[share..].iter().map(|o| o.shard).collect();
            for shard in extra {
                self.release(shard).await?;
            }
            return Ok(());
        }
        // Start where this worker's name points, so workers starting
        // together try different shards first.
        let offset = self.options.id.bytes().map(u32::from).sum::<u32>() % shards;
        for s in (0..shards).map(|i| (i + offset) % shards) {
            if self.owned.len() >= share {
                break;
            }
            if self.owned.iter().any(|o| o.shard == s) {
                continue;
            }
            if let Ok(revision) = self
                .site
                .leases
                .create(shard_key(s), self.options.id.clone().into())
                .await
            {
                // Kept from now: loading a large shard may outlast the lease.
                let id = self.options.id.clone().into_bytes();
                self.keeper.hold(shard_key(s), id, revision).await;
                if let Err(e) = self.take(s).await {
                    // Not kept: a lease renewed for a shard nobody fuses
                    // would hold it up for as long as this worker lives.
                    self.keeper.give_back(&shard_key(s)).await;
                    return Err(e);
                }
            }
        }
        Ok(())
    }

    /// Fusion workers whose heartbeats have not expired.
    async fn live_workers(&self) -> Result<u32> {
        let beats = live_entries(&self.site.workers).await?;
        Ok(beats
            .iter()
            .filter(|(k, _)| !k.starts_with("tracker."))
            .count() as u32)
    }

    /// Loads `shard` from its last checkpoint, now that its lease is ours.
    async fn take(&mut self, shard: u32) -> Result<()> {
        let (manifest, manifest_revision) = match read_manifest(&self.site, shard).await? {
            Some((m, r)) => (m, Some(r)),
            None => (Manifest::default(), None),
        };
        let (manifest, manifest_revision, blocks) =
            load_shard(&self.site, shard, manifest, manifest_revision).await?;
        self.fuser
            .volume
            .restore(blocks.into_values().collect(), 0)?;
        // Loading many shards in a row is progress too, for the keeper.
        self.keeper.alive();
        eprintln!(
            "worker {}: took shard {shard} at message {} ({} frames fused)",
            self.options.id, manifest.seq, manifest.frames
        );
        self.owned.push(Owned {
            shard,
            next: manifest.seq + 1,
            frames: manifest.frames,
            rejected: manifest.rejected,
            manifest,
            manifest_revision,
            saved_at: self.fuser.volume.frames(),
            unanswered: Vec::new(),
        });
        Ok(())
    }

    /// Checkpoints `shard` and gives its lease back.
    async fn release(&mut self, shard: u32) -> Result<()> {
        let Some(o) = self.owned.iter().find(|o| o.shard == shard) else {
            return Ok(());
        };
        if o.unsaved() {
            self.checkpoint(shard).await?;
        }
        if self.owned.iter().any(|o| o.shard == shard) {
            self.keeper.give_back(&shard_key(shard)).await;
            self.forget(shard).await;
        }
        Ok(())
    }

    /// Gives every shard back, checkpointed, and says goodbye.
    async fn release_all(&mut self) -> Result<()> {
        let shards: Vec<u32> = self.owned.iter().map(|o| o.shard).collect();
        for shard in shards {
            self.release(shard).await?;
        }
        self.keeper.end_beat(&self.options.id).await;
        Ok(())
    }
}
