//! A site in the browser view (`serve --nats`): the server follows the
//! shards' checkpoints as they are committed, loads the segments it has
//! not seen into a TSDF of the whole site, and sends viewers the parts that
//! changed. Meshing here, where every shard's blocks meet, is what makes
//! the view seamless: a block's mesh needs the blocks above it, which other
//! shards (other workers) own.

use crate::checkpoint::{load_blocks, read_manifest, Manifest};
use crate::error::Result;
use crate::fetch::frames_by_sensor;
use crate::site::Site;
use crate::status::heartbeats;
use depthmesh::session::{Backend, Session, SessionConfig};
use depthmesh_server::Server;
use serde_json::json;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// How often the checkpoints are looked at.
const POLL: Duration = Duration::from_millis(500);

/// Shows `site` on `server` as the view `site-NAME` until `stop` is set.
/// The view appears once the site has settings and a sensor (its camera
/// places the sensor's frustum in the page).
pub async fn follow(site: &Site, server: &Server, stop: &AtomicBool) -> Result<()> {
    let (config, camera) = loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(());
        }
        let sensor = frames_by_sensor(site).await?.into_keys().next();
        if let (Some(config), Some(sensor)) = (site.config().await?, sensor) {
            if let Some(k) = site.sensor(&sensor).await? {
                break (config, k);
            }
        }
        tokio::time::sleep(POLL).await;
    };
    let mut session = Session::new(SessionConfig {
        intrinsics: camera,
        map: config.map(),
        tracking: None,
    })?;
    let name = format!("site-{}", site.name);
    let mut view = server
        .add_view(&name, &session)
        .map_err(|e| crate::ClusterError::site(&site.name, e))?;
    let mut seen: Vec<Option<Manifest>> = vec![None; config.regions.shards as usize];
    let (mut settled, mut viewers) = (false, 0);
    while !stop.load(Ordering::Relaxed) {
        let changed = load_new(site, &mut seen, &mut session).await?;
        // Settled: a poll found nothing new after one that did, or a
        // viewer joined (who is sent the whole map).
        let joined = view.viewers() > viewers;
        viewers = view.viewers();
        let now_settled = !changed && (!settled || joined);
        if changed || now_settled {
            // What the view holds: the checkpoints just read, not the
            // workers' live positions (`cluster status` reads those).
            let (workers, _) = heartbeats(site).await?;
            let fps = workers.iter().map(|w| w.frames_per_second).reduce(f64::min);
            let held = |f: fn(&Manifest) -> u64| seen.iter().map(|m| m.as_ref().map_or(0, f)).min();
            let frames = held(|m| m.frames).unwrap_or(0);
            let lag = site
                .last_seq()
                .await?
                .saturating_sub(held(|m| m.seq).unwrap_or(0));
            let figures = json!({
                "frames": frames,
                "fused": frames,
                "lost_frames": 0,
                "fps": fps.unwrap_or(0.0),
                "tracking": format!("{} workers, lag {lag}", workers.len()),
            });
            view.publish(&mut session, figures, now_settled);
        }
        settled = !changed;
        tokio::time::sleep(POLL).await;
    }
    Ok(())
}

/// Loads into `session` the segments committed since `seen`; whether any were.
async fn load_new(
    site: &Site,
    seen: &mut [Option<Manifest>],
    session: &mut Session,
) -> Result<bool> {
    let mut changed = false;
    for (shard, known) in seen.iter_mut().enumerate() {
        let Some((manifest, _)) = read_manifest(site, shard as u32).await? else {
            continue;
        };
        if known.as_ref() == Some(&manifest) {
            continue;
        }
        // Segments already loaded are skipped; a shard written whole again
        // (compacted) is loaded whole, which replaces what it held.
        let old: &[String] = known.as_ref().map_or(&[], |m| &m.segments);
        let new = Manifest {
            segments: manifest
                .segments
                .iter()
                .filter(|s| !old.contains(s))
                .cloned()
                .collect(),
            ..manifest.clone()
        };
        let blocks = match load_blocks(site, shard as u32, &new).await {
            Ok(b) => b,
            // Written whole and its older segments deleted meanwhile: the
            // next poll reads the newer manifest.
            Err(_) => continue,
        };
        if let Backend::Tsdf(t) = session.backend_mut() {
            let frames = t.volume().frames() + 1;
            t.restore(blocks.into_values().collect(), frames)?;
        }
        *known = Some(manifest);
        changed = true;
    }
    Ok(changed)
}
