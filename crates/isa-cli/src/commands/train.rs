//! `isa train`: forest parameters (defaults, `--params`, flags, through the core's overlay), a
//! training-set file, a model file with the typed metadata and inference defaults the training
//! set's metadata carries.

use std::io::Write;
use std::time::Instant;

use isa_core::metadata::split_metadata;
use isa_core::{trainset_io, Forest, ForestParams};

use super::{flags_json, params_file, FLAGS};
use crate::args::TrainArgs;
use crate::error::{CliError, CliResult};
use crate::progress::{bar, spinner};

pub fn run(a: TrainArgs) -> CliResult<()> {
    let mut p = ForestParams::default();
    if let Some((json, source)) = params_file(a.params.as_deref())? {
        p.overlay(&json, &source)?;
    }
    p.overlay(&flags_json(&a.flags), FLAGS)?;
    let params = p.check()?;

    if !a.trainset.exists() {
        return Err(CliError::missing(&a.trainset, "training-set file"));
    }
    let pb = spinner(a.run.quiet, format!("reading {}", a.trainset.display()));
    let ts = trainset_io::read(&a.trainset)?;
    pb.finish_and_clear();
    // Metadata written by another version may name inference keys this one lacks: skipped.
    let (metadata, predict_defaults) = split_metadata(
        &ts.metadata,
        &format!("metadata of {}", a.trainset.display()),
        true,
    )?;
    if params.quality.uses_q2() && ts.link_angles.is_none() {
        return Err(CliError::param(format!(
            "quality {} needs link angles (Q2), but {} has none: use --quality Q1 or Q1+Q3, or write link_angles",
            params.quality.as_str(),
            a.trainset.display()
        )));
    }
    if params.quality.uses_q3() && ts.node_offsets.is_none() {
        return Err(CliError::param(format!(
            "quality {} needs node offsets (Q3), but {} has none: use --quality Q1 or Q1+Q2, or write node_offsets",
            params.quality.as_str(),
            a.trainset.display()
        )));
    }
    let msg = format!(
        "training {} trees (depth <= {}, {}) on {} parts of {} images",
        params.n_trees,
        params.max_depth,
        params.quality.as_str(),
        ts.n_parts(),
        ts.store.len()
    );
    if a.run.threads == Some(0) {
        return Err(CliError::param("--threads must be at least 1".into()));
    }
    let pb = bar(
        a.run.quiet,
        params.n_trees as u64,
        &format!("training {} trees", params.n_trees),
    );
    let t0 = Instant::now();
    let mut forest = Forest::fit_with_progress(
        &params,
        &ts.training_set(),
        metadata,
        a.run.threads,
        &|done| pb.set_position(done as u64),
    )?;
    forest.predict_defaults = predict_defaults;
    let secs = t0.elapsed().as_secs_f64();
    pb.finish_and_clear();
    forest.save(&a.output)?;
    let (nodes, leaves) = forest.size();
    if !a.run.quiet {
        // Not eprintln!: it panics when standard error is closed.
        let _ = writeln!(
            std::io::stderr(),
            "{msg}: done in {secs:.1} s; {nodes} nodes, {leaves} leaves; wrote {}",
            a.output.display()
        );
    }
    Ok(())
}
