//! `depthmesh eval`: accuracy of a run's output against a reference.

mod relocalise;

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use depthmesh::dataset::{Dataset, DatasetOptions, FrameRange};
use depthmesh::eval::trajectory::trajectory_error;
use depthmesh::trajectory::read_tum;
use depthmesh::Pose;
use serde_json::json;
use std::path::{Path, PathBuf};

/// What `eval` compares.
#[derive(Subcommand, Debug)]
pub enum EvalCommand {
    /// Trajectory error (ATE raw and aligned, RPE) of an estimate against a reference.
    Trajectory(TrajectoryArgs),
    /// Relocalisation: query frames found again in a map built from other frames.
    Relocalise(relocalise::RelocaliseArgs),
}

/// Flags of `depthmesh eval trajectory`.
#[derive(Args, Debug)]
pub struct TrajectoryArgs {
    /// Estimated trajectory (TUM format, e.g. a run's trajectory.txt).
    pub estimate: PathBuf,
    /// Reference: a TUM trajectory file, or a dataset folder (7-Scenes
    /// frames folder or TUM RGB-D folder) whose poses serve as reference.
    pub reference: PathBuf,
    /// With a dataset folder as reference: only these frames' poses, `A..B`
    /// (half-open, as `reconstruct --frames`), so a run over part of a
    /// sequence is judged against that part.
    #[arg(long)]
    pub frames: Option<FrameRange>,
    /// Poses further apart in time than this (seconds) are not matched.
    #[arg(long, default_value_t = 0.02, allow_negative_numbers = true)]
    pub max_dt: f64,
    /// Print one JSON line instead of text.
    #[arg(long)]
    pub json: bool,
    /// Fail (after printing the figures) when fewer than this share of the
    /// reference's poses have an estimate: a run that lost most frames has
    /// few poses to compare, and their error says nothing of the rest. 0
    /// accepts any coverage.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub min_coverage: f64,
}

/// Runs `eval`.
pub fn run(command: &EvalCommand) -> Result<()> {
    match command {
        EvalCommand::Trajectory(args) => trajectory(args),
        EvalCommand::Relocalise(args) => relocalise::run(args),
    }
}

fn trajectory(args: &TrajectoryArgs) -> Result<()> {
    if !(args.max_dt >= 0.0 && args.max_dt.is_finite()) {
        bail!(
            "--max-dt must be a non-negative number of seconds, got {}",
            args.max_dt
        );
    }
    if !(0.0..=1.0).contains(&args.min_coverage) {
        bail!(
            "--min-coverage must be a share in [0, 1], got {}",
            args.min_coverage
        );
    }
    let estimate = read_tum(&args.estimate)?;
    let reference = read_reference(&args.reference, args.frames)?;
    let e = trajectory_error(&estimate, &reference, args.max_dt)?;
    let coverage = e.matched as f64 / reference.len() as f64;
    if args.json {
        println!(
            "{}",
            json!({
                "matched": e.matched,
                "estimated_poses": estimate.len(),
                "reference_poses": reference.len(),
                "coverage": coverage,
                "ate_rmse_cm": e.ate_rmse * 100.0,
                "ate_rmse_aligned_cm": e.ate_rmse_aligned * 100.0,
                "ate_max_cm": e.ate_max * 100.0,
                "rpe_translation_mm": e.rpe_translation * 1000.0,
                "rpe_rotation_deg": e.rpe_rotation_degrees,
            })
        );
    } else {
        println!(
            "matched {} of {} estimated poses: {:.0} % of the reference's {} poses",
            e.matched,
            estimate.len(),
            100.0 * coverage,
            reference.len()
        );
        println!(
            "ATE RMSE {:.2} cm (max {:.2} cm); after rigid alignment {:.2} cm",
            e.ate_rmse * 100.0,
            e.ate_max * 100.0,
            e.ate_rmse_aligned * 100.0
        );
        println!(
            "RPE per step RMSE {:.2} mm, {:.3}°",
            e.rpe_translation * 1000.0,
            e.rpe_rotation_degrees
        );
    }
    if coverage < args.min_coverage {
        bail!(
            "the estimate covers only {} of the reference's {} poses ({:.0} %, below --min-coverage {}): \
             the frames the run lost have no estimate, so the error above describes only the frames it kept",
            e.matched,
            reference.len(),
            100.0 * coverage,
            args.min_coverage
        );
    }
    Ok(())
}

/// A TUM file, or the poses of a dataset folder (of `frames` only, if given).
fn read_reference(path: &Path, frames: Option<FrameRange>) -> Result<Vec<(f64, Pose)>> {
    if path.is_dir() {
        let options = DatasetOptions {
            frames,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(path, &options)?;
        let poses = dataset.trajectory()?;
        if poses.is_empty() {
            bail!(
                "{}: the dataset has no poses to compare with",
                path.display()
            );
        }
        Ok(poses)
    } else if frames.is_some() {
        bail!(
            "--frames selects frames of a dataset folder; {} is a trajectory file",
            path.display()
        );
    } else {
        Ok(read_tum(path)?)
    }
}
