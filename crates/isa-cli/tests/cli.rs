//! The `isa` binary end to end: train -> inspect -> predict on a small synthetic set (poses
//! recovered, JSON and BOP CSV outputs, BOP scene folders with depth_scale), and the exit codes
//! and messages for bad inputs.
//!
//! Over 600 lines: every command's end-to-end cases share this file's fixtures (the trained
//! models), which are built once per test binary.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use isa_core::trainset_io::{self, TrainSetData};
use isa_core::vote::{matrix_to_quat, quat_angle, synth, Intrinsics};
use isa_core::{sample_parts, DepthStore};

const K: Intrinsics = Intrinsics {
    fx: 200.0,
    fy: 200.0,
    cx: 79.5,
    cy: 59.5,
};

fn tmp(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("isa-cli-tests");
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

fn isa(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_isa"))
        .args(args)
        .output()
        .expect("run isa")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn poses() -> Vec<([[f64; 3]; 3], [f64; 3])> {
    (0..12)
        .map(|i| synth::look_at(i as f64 * std::f64::consts::TAU / 12.0, 0.35, 2.5))
        .collect()
}

/// A training set of 12 views of the synthetic chair (160x120).
fn write_trainset(path: &Path, metadata: &str) {
    let chair = synth::chair();
    let mut store = DepthStore::new();
    let poses = poses();
    for (r, t) in &poses {
        store
            .push(160, 120, &synth::render(&chair, *r, *t, &K, 160, 120))
            .unwrap();
    }
    let parts = sample_parts(&store, 2, Some(400), 7).unwrap();
    let (mut offsets, mut rotations) = (Vec::new(), Vec::new());
    for (i, (r, t)) in poses.iter().enumerate() {
        let mine: Vec<[i32; 3]> = parts.iter().filter(|p| p[0] == i as i32).copied().collect();
        let (o, q) = synth::targets(&mine, store.image(i).data, 160, *r, *t, &K);
        offsets.extend(o);
        rotations.extend(q);
    }
    let ts = TrainSetData {
        store,
        parts,
        offsets,
        rotations,
        link_angles: None,
        node_offsets: None,
        metadata: metadata.into(),
    };
    trainset_io::write(&ts, path).unwrap();
}

/// `isa train TS -o OUT --quality Q1 --quiet` plus `extra` flags.
fn train_q1(ts: &Path, out: &Path, extra: &[&str]) -> Output {
    let (ts, out) = (ts.to_str().unwrap(), out.to_str().unwrap());
    let mut args = vec!["train", ts, "-o", out, "--quality", "Q1", "--quiet"];
    args.extend_from_slice(extra);
    isa(&args)
}

/// Trained once for all tests: the model path.
fn model() -> &'static PathBuf {
    static MODEL: OnceLock<PathBuf> = OnceLock::new();
    MODEL.get_or_init(|| {
        let ts = tmp("chair.isat");
        write_trainset(&ts, r#"{"category": "chair", "ssc": [0, 0, 0]}"#);
        let m = tmp("chair.isaf");
        let o = train_q1(
            &ts,
            &m,
            &[
                "--n-trees",
                "4",
                "--max-depth",
                "14",
                "--n-candidates",
                "60",
                "--min-samples-split",
                "10",
                "--min-samples-leaf",
                "3",
            ],
        );
        assert!(o.status.success(), "train failed: {}", stderr(&o));
        m
    })
}

fn write_png(path: &Path, w: usize, h: usize, px: Vec<u16>) {
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w as u32, h as u32, px)
        .unwrap()
        .save(path)
        .unwrap();
}

/// Training view `i` of the chair in a 320x240 frame, shifted sideways: (depth, K, R, t).
fn test_view(i: usize) -> (Vec<u16>, Intrinsics, [[f64; 3]; 3], [f64; 3]) {
    let k = Intrinsics {
        cx: 159.5,
        cy: 119.5,
        ..K
    };
    let (r, mut t) = poses()[i];
    t[0] += 0.3;
    (synth::render(&synth::chair(), r, t, &k, 320, 240), k, r, t)
}

fn err_t(a: &[f64], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// [`test_view`] `i` written to the PNG `name` (in the temporary folder): its path, intrinsics
/// and true pose.
fn test_png(i: usize, name: &str) -> (PathBuf, Intrinsics, [[f64; 3]; 3], [f64; 3]) {
    let (depth, k, r, t) = test_view(i);
    let png = tmp(name);
    write_png(&png, 320, 240, depth);
    (png, k, r, t)
}

/// Intrinsics of focal length `f` (pixels) in u and v, principal point `(cx, cy)`.
fn square_pixels(f: f64, cx: f64, cy: f64) -> Intrinsics {
    Intrinsics {
        fx: f,
        fy: f,
        cx,
        cy,
    }
}

/// The four numbers of `-k FX FY CX CY`.
fn k_args(k: &Intrinsics) -> [String; 4] {
    [k.fx, k.fy, k.cx, k.cy].map(|v| v.to_string())
}

/// `isa predict MODEL PNG -k FX FY CX CY` plus `extra`.
fn predict_k(model: &str, png: &Path, k: &Intrinsics, extra: &[&str]) -> Output {
    let kk = k_args(k);
    let mut args = vec!["predict", model, png.to_str().unwrap(), "-k"];
    args.extend(kk.iter().map(String::as_str));
    args.extend_from_slice(extra);
    isa(&args)
}

/// Asserts `o` exited with `code` and its standard error holds every one of `needles`.
fn expect_exit(o: &Output, code: i32, needles: &[&str]) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(code), "{e}");
    for n in needles {
        assert!(e.contains(n), "{n:?} not in: {e}");
    }
}

/// The numbers of a JSON array.
fn nums(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// The best hypothesis of the first image of a successful `isa predict` (JSON on stdout).
fn best(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", stderr(o));
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    doc["images"][0]["hypotheses"][0].clone()
}

#[test]
fn train_inspect_predict_round_trip() {
    let m = model().to_str().unwrap();
    // inspect: text and JSON
    let o = isa(&["inspect", m]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("4 trees") && text.contains("chair") && text.contains("Q1"),
        "{text}"
    );
    let o = isa(&["inspect", m, "--json"]);
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(doc["n_trees"], 4);
    // A one-class forest is written as format 2 (format 3 adds leaf weights).
    assert_eq!(
        (
            doc["format_version"].as_u64(),
            doc["leaf_weights"].as_bool()
        ),
        (Some(2), Some(false))
    );
    assert_eq!(doc["metadata"]["category"], "chair");
    assert_eq!(doc["params"]["max_depth"], 14);
    assert_eq!(doc["trees"].as_array().unwrap().len(), 4);

    // predict: JSON on stdout
    let (png, k, r, t) = test_png(5, "view5.png");
    let o = predict_k(m, &png, &k, &["--stride", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let hyps = doc["images"][0]["hypotheses"].as_array().unwrap();
    assert!(!hyps.is_empty() && hyps.len() <= 5);
    let best = &hyps[0];
    let tt = nums(&best["t"]);
    assert!(err_t(&tt, t) < 0.03, "translation {tt:?} vs {t:?}");
    let q = nums(&best["quaternion"]);
    assert!(quat_angle([q[0], q[1], q[2], q[3]], matrix_to_quat(r)).to_degrees() < 5.0);
    let scores: Vec<f64> = hyps.iter().map(|h| h["score"].as_f64().unwrap()).collect();
    assert!(scores.windows(2).all(|w| w[0] >= w[1]));
    assert_eq!(doc["params"]["stride"], 2);
}

#[test]
fn predict_reads_the_models_defaults_and_flags_win() {
    let ts = tmp("defaults.isat");
    // As Python's pipeline.train_forest stores them (flat keys), plus one this version lacks.
    write_trainset(
        &ts,
        r#"{"predict_defaults": {"stride": 3, "max_hypotheses": 1, "from_the_future": 1}}"#,
    );
    let m = tmp("defaults.isaf");
    let o = train_q1(&ts, &m, &["--n-trees", "2", "--max-depth", "10"]);
    assert!(o.status.success(), "train failed: {}", stderr(&o));
    let (png, k, _, _) = test_png(5, "defaults-view5.png");
    let run = |extra: &[&str]| -> serde_json::Value {
        let o = predict_k(m.to_str().unwrap(), &png, &k, extra);
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let doc = run(&[]);
    assert_eq!(doc["params"]["stride"], 3);
    assert_eq!(doc["params"]["vote"]["max_hypotheses"], 1);
    assert!(doc["images"][0]["hypotheses"].as_array().unwrap().len() <= 1);
    let doc = run(&["--stride", "2", "--max-hypotheses", "4"]);
    assert_eq!(doc["params"]["stride"], 2);
    assert_eq!(doc["params"]["vote"]["max_hypotheses"], 4);
}

#[test]
fn bop_scene_folder_with_depth_scale_to_csv() {
    let m = model().to_str().unwrap();
    let scene = tmp("000007");
    std::fs::create_dir_all(scene.join("depth")).unwrap();
    let mut cams = serde_json::Map::new();
    let mut truth = Vec::new();
    for (id, view) in [(3u64, 2usize), (4, 8)] {
        let (depth, k, _r, t) = test_view(view);
        // BOP-style: PNG values in 0.1 mm units, depth_scale 0.1
        let px: Vec<u16> = depth
            .iter()
            .map(|&d| (u32::from(d) * 10).min(65535) as u16)
            .collect();
        write_png(
            &scene.join("depth").join(format!("{id:06}.png")),
            320,
            240,
            px,
        );
        cams.insert(
            id.to_string(),
            serde_json::json!({"cam_K": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0], "depth_scale": 0.1}),
        );
        truth.push((id, t));
    }
    std::fs::write(
        scene.join("scene_camera.json"),
        serde_json::Value::Object(cams).to_string(),
    )
    .unwrap();
    let csv = tmp("results.csv");
    let o = isa(&[
        "predict",
        m,
        "--scene",
        scene.to_str().unwrap(),
        "--format",
        "bop",
        "--obj-id",
        "5",
        "--stride",
        "2",
        "--max-hypotheses",
        "2",
        "-o",
        csv.to_str().unwrap(),
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("scene_id,im_id,obj_id,score,R,t,time"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(rows.len() >= 2 && rows.len() <= 4);
    for (id, t) in truth {
        let row = rows
            .iter()
            .find(|r| r[1] == id.to_string())
            .expect("a row per image");
        assert_eq!((row[0], row[2]), ("7", "5"));
        assert_eq!(row[4].split(' ').count(), 9);
        let tmm: Vec<f64> = row[5]
            .split(' ')
            .map(|v| v.parse::<f64>().unwrap() / 1000.0)
            .collect();
        assert!(err_t(&tmm, t) < 0.03, "image {id}: {tmm:?} vs {t:?}");
        assert!(row[6].parse::<f64>().unwrap() >= 0.0);
    }
}

#[test]
fn missing_files_exit_3_naming_them() {
    let o = isa(&[
        "predict",
        "/nonexistent/model.isaf",
        "x.png",
        "-k",
        "1",
        "1",
        "0",
        "0",
    ]);
    expect_exit(&o, 3, &["/nonexistent/model.isaf", "does not exist"]);
    let o = isa(&["inspect", "/nonexistent/model.isaf"]);
    expect_exit(&o, 3, &[]);
    let o = isa(&[
        "train",
        "/nonexistent/t.isat",
        "-o",
        tmp("never.isaf").to_str().unwrap(),
    ]);
    expect_exit(&o, 3, &["/nonexistent/t.isat"]);
    let m = model().to_str().unwrap();
    let o = predict_k(m, Path::new("/nonexistent/depth.png"), &K, &[]);
    expect_exit(&o, 3, &["/nonexistent/depth.png"]);
}

#[test]
fn corrupt_model_and_trainset_exit_4() {
    let bad = tmp("corrupt.isaf");
    std::fs::write(&bad, b"this is not a model file at all").unwrap();
    let o = isa(&["inspect", bad.to_str().unwrap()]);
    expect_exit(&o, 4, &["corrupt.isaf", "invalid model file"]);
    // A real model with one byte flipped: the checksum catches it.
    let mut bytes = std::fs::read(model()).unwrap();
    let n = bytes.len();
    bytes[n / 2] ^= 0x55;
    let flipped = tmp("flipped.isaf");
    std::fs::write(&flipped, bytes).unwrap();
    let png = tmp("small.png");
    write_png(&png, 160, 120, vec![1000; 160 * 120]);
    let o = predict_k(flipped.to_str().unwrap(), &png, &K, &[]);
    expect_exit(&o, 4, &["flipped.isaf"]);
    let badts = tmp("corrupt.isat");
    std::fs::write(&badts, b"ISATRAIN garbage").unwrap();
    let o = isa(&[
        "train",
        badts.to_str().unwrap(),
        "-o",
        tmp("never.isaf").to_str().unwrap(),
    ]);
    expect_exit(&o, 4, &["corrupt.isat"]);
}

#[test]
fn wrong_images_exit_4_with_reason() {
    let m = model().to_str().unwrap();
    let k525 = square_pixels(525.0, 319.5, 239.5);
    // Too small for the intrinsics (principal point outside the image).
    let small = tmp("tiny.png");
    write_png(&small, 20, 10, vec![1000; 200]);
    let o = predict_k(m, &small, &k525, &[]);
    expect_exit(&o, 4, &["tiny.png", "20x10", "wrong-size"]);
    // A camera.json that names the size.
    let cam = tmp("camera.json");
    std::fs::write(&cam, r#"{"fx": 200, "fy": 200, "cx": 79.5, "cy": 59.5, "width": 160, "height": 120, "depth_scale": 1}"#)
        .unwrap();
    let wide = tmp("wide.png");
    write_png(&wide, 200, 120, vec![1000; 200 * 120]);
    let o = isa(&[
        "predict",
        m,
        wide.to_str().unwrap(),
        "-c",
        cam.to_str().unwrap(),
    ]);
    expect_exit(&o, 4, &["wide.png", "200x120", "160x120"]);
    // 8-bit PNG; not an image at all.
    let k20 = square_pixels(20.0, 7.5, 7.5);
    let eight = tmp("eight.png");
    image::GrayImage::from_raw(16, 16, vec![7u8; 256])
        .unwrap()
        .save(&eight)
        .unwrap();
    expect_exit(
        &predict_k(m, &eight, &k20, &[]),
        4,
        &["eight.png", "16-bit"],
    );
    let txt = tmp("notimage.png");
    std::fs::write(&txt, "hello").unwrap();
    expect_exit(&predict_k(m, &txt, &k20, &[]), 4, &["notimage.png"]);
}

#[test]
fn bad_parameters_exit_5_and_usage_exit_2() {
    let m = model().to_str().unwrap();
    let png = tmp("plain.png");
    write_png(&png, 160, 120, vec![1000; 160 * 120]);
    expect_exit(&predict_k(m, &png, &K, &["--stride", "0"]), 5, &["stride"]);
    let k0 = Intrinsics { fx: 0.0, ..K };
    expect_exit(&predict_k(m, &png, &k0, &[]), 5, &["intrinsics"]);
    let params = tmp("params.json");
    std::fs::write(&params, r#"{"vote": {"bandwith": 1}}"#).unwrap();
    let o = predict_k(m, &png, &K, &["--params", params.to_str().unwrap()]);
    expect_exit(&o, 5, &["bandwith"]);
    expect_exit(
        &predict_k(m, &png, &K, &["--depth-scale", "0"]),
        5,
        &["depth_scale"],
    );
    let ts = tmp("q2.isat");
    write_trainset(&ts, "{}");
    let never = tmp("never.isaf");
    for (quality, says) in [("Q1+Q2", "link angles"), ("Q7", "quality")] {
        let (ts, never) = (ts.to_str().unwrap(), never.to_str().unwrap());
        let o = isa(&["train", ts, "-o", never, "--quality", quality]);
        expect_exit(&o, 5, &[says]);
    }
    expect_exit(&isa(&["predict"]), 2, &[]);
    expect_exit(&isa(&["predict", m]), 5, &["PNG"]);
}

/// Issue 20: `isa inspect model | head` panicked on the closed pipe (exit 101).
#[test]
fn a_closed_stdout_ends_quietly() {
    use std::process::Stdio;
    let m = model().to_str().unwrap();
    for args in [vec!["inspect", m], vec!["inspect", m, "--json"]] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_isa"))
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take()); // the reader is gone before the first byte
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(0), "{args:?}: {}", stderr(&o));
        assert!(!stderr(&o).contains("panicked"), "{}", stderr(&o));
    }
    // A closed standard error does not panic either (the error message is dropped).
    let o = Command::new(env!("CARGO_BIN_EXE_isa"))
        .args(["inspect", "/nonexistent/model.isaf"])
        .stderr(Stdio::null())
        .status()
        .unwrap();
    assert_eq!(o.code(), Some(3));
}

#[test]
fn unwritable_output_is_exit_3_naming_it_and_leaves_nothing() {
    let m = model().to_str().unwrap();
    let png = tmp("unwritable.png");
    write_png(&png, 160, 120, vec![1500; 160 * 120]);
    let dir = tmp("unwritable-out");
    std::fs::create_dir_all(&dir).unwrap();
    for out in [
        "/nonexistent/dir/out.json".to_string(),
        dir.display().to_string(),
    ] {
        let o = predict_k(m, &png, &K, &["-q", "-o", &out]);
        expect_exit(&o, 3, &[out.as_str()]);
    }
    let temps = std::fs::read_dir(dir.parent().unwrap())
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .contains(".isa-tmp-")
        })
        .count();
    assert_eq!(temps, 0, "no temporary file left");
    let ts = tmp("chair.isat");
    let o = train_q1(&ts, Path::new("/nonexistent/dir/m.isaf"), &[]);
    expect_exit(&o, 3, &["/nonexistent/dir/m.isaf"]);
}

/// Issue 20: `--position-bandwidth nan` failed with a message naming no flag; `-k` could not
/// take a negative number.
#[test]
fn number_flags_name_themselves_and_negative_numbers_parse() {
    let m = model().to_str().unwrap();
    let png = tmp("flags.png");
    write_png(&png, 160, 120, vec![1500; 160 * 120]);
    let p = png.to_str().unwrap();
    for (flag, v) in [
        ("--position-bandwidth", "nan"),
        ("--nms-radius", "inf"),
        ("--min-depth", "-inf"),
    ] {
        let arg = format!("{flag}={v}");
        let o = isa(&["predict", m, p, "-k", "200", "200", "79.5", "59.5", &arg]);
        expect_exit(&o, 2, &[flag, "finite"]);
    }
    let ts = tmp("chair.isat");
    let o = train_q1(&ts, &tmp("never.isaf"), &["--bag-fraction", "nan"]);
    expect_exit(&o, 2, &["--bag-fraction"]);
    // A negative principal point parses (clap took "-3" for a flag before) and is refused as
    // outside the image: an input error naming the image.
    let o = isa(&["predict", m, p, "-k", "200", "200", "-3", "59.5"]);
    expect_exit(&o, 4, &["principal point", "flags.png"]);
    let o = isa(&["predict", m, p, "-k", "200", "200", "79.5", "59.5", "-q"]);
    expect_exit(&o, 0, &[]);
}

/// SIGINT while training: the process ends by the signal, the model file is the old one (or
/// absent), and the next write leaves no temporary file.
#[cfg(unix)]
#[test]
fn sigint_while_training_leaves_no_half_written_model() {
    use std::os::unix::process::ExitStatusExt;
    let ts = tmp("chair.isat");
    model(); // writes the training set
    let dir = tmp("sigint");
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("m.isaf");
    std::fs::write(&out, b"old").unwrap();
    for delay_ms in [50u64, 200, 400] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_isa"))
            .args([
                "train",
                ts.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "--quality",
                "Q1",
                "--quiet",
                "--n-trees",
                "30",
            ])
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status();
        let st = child.wait().unwrap();
        let bytes = std::fs::read(&out).unwrap();
        if st.signal() == Some(2) {
            assert_eq!(bytes, b"old");
        } else {
            assert!(
                st.success() && isa_core::Forest::from_bytes(&bytes).is_ok(),
                "{st:?}"
            );
            std::fs::write(&out, b"old").unwrap();
        }
    }
    isa_core::atomic::write_bytes(&out, b"next").unwrap();
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["m.isaf"]);
}

/// A model of the synthetic chair whose metadata holds its box (size, SSC offset), and its
/// shape library (surface samples of the chair's boxes, written as the core writes `.isl`).
fn detect_model() -> &'static PathBuf {
    static MODEL: OnceLock<PathBuf> = OnceLock::new();
    MODEL.get_or_init(|| {
        let ts = tmp("boxed.isat");
        write_trainset(
            &ts,
            r#"{"category": "chair", "box": {"category": "chair", "size": [0.46, 0.445, 0.92], "ssc_offset": [0.0, 0.0025, -0.01]}}"#,
        );
        let m = tmp("boxed.isa");
        let o = train_q1(&ts, &m, &["--n-trees", "4", "--max-depth", "14", "--n-candidates", "60"]);
        assert!(o.status.success(), "train failed: {}", stderr(&o));
        let (mut pts, mut nrm) = (Vec::new(), Vec::new());
        let n = 12;
        for b in synth::chair() {
            for axis in 0..3 {
                for sign in [-1.0f64, 1.0] {
                    for i in 0..n {
                        for j in 0..n {
                            let (a, c) = ((axis + 1) % 3, (axis + 2) % 3);
                            let mut p = b.centre;
                            p[axis] += sign * b.half[axis];
                            p[a] += b.half[a] * (2.0 * (i as f64 + 0.5) / n as f64 - 1.0);
                            p[c] += b.half[c] * (2.0 * (j as f64 + 0.5) / n as f64 - 1.0);
                            let mut q = [0f32; 3];
                            q[axis] = sign as f32;
                            pts.push(p.map(|x| x as f32));
                            nrm.push(q);
                        }
                    }
                }
            }
        }
        let (lo, hi) = ([-0.23, -0.225, -0.45], [0.23, 0.22, 0.47]);
        let np = pts.len();
        let lib = isa_core::scene::ShapeLibrary::new("chair".into(), vec!["synth".into()], None, np, pts, nrm, vec![0.01], vec![[lo, hi]])
            .unwrap();
        lib.save(&m.with_extension("shapes.isl")).unwrap();
        m
    })
}

#[test]
fn detect_two_categories_one_object_json_and_bop() {
    let m = detect_model().to_str().unwrap().to_string();
    let (png, k, r, t) = test_png(3, "000007.png");
    let g = format!("--gravity={},{},{}", -r[0][2], -r[1][2], -r[2][2]); // the object's -z (down) in the camera
    let [fx, fy, cx, cy] = k_args(&k);
    let (chair, toilet) = (format!("chair={m}"), format!("toilet={m}"));
    let base = [
        "detect",
        "--model",
        &chair,
        "--model",
        &toilet,
        png.to_str().unwrap(),
        "-k",
        &fx,
        &fy,
        &cx,
        &cy,
        &g,
        "--stride",
        "2",
        "-q",
    ];
    let o = isa(&base);
    assert!(o.status.success(), "{}", stderr(&o));
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let img = &doc["images"][0];
    assert_eq!(img["gravity_source"], "given");
    assert_eq!(
        doc["models"][0]["shapes"].as_str().unwrap(),
        detect_model()
            .with_extension("shapes.isl")
            .to_str()
            .unwrap()
    );
    let dets = img["detections"].as_array().unwrap();
    // Both models fire on the one chair: one verified detection of it survives, on the truth
    // (refuted ones, score below 0, may stay beside it: their boxes overlap it too little).
    let near: Vec<&serde_json::Value> = dets
        .iter()
        .filter(|d| err_t(&nums(&d["t"]), t) < 0.3 && d["score"].as_f64().unwrap() > 0.0)
        .collect();
    assert_eq!(near.len(), 1, "{dets:?}");
    let best = &dets[0];
    assert!(err_t(&nums(&best["t"]), t) < 0.05, "{best}");
    assert!(
        best["score"].as_f64().unwrap() > 0.5 && best["shape"] == 0,
        "{best}"
    );
    let scores: Vec<f64> = dets.iter().map(|d| d["score"].as_f64().unwrap()).collect();
    assert!(scores.windows(2).all(|w| w[0] >= w[1]));
    // BOP CSV: one header, a row per detection, obj_id by category.
    let csv = tmp("detect.csv");
    let mut args = base.to_vec();
    args.extend([
        "--format",
        "bop",
        "--obj-id",
        "toilet=7",
        "--scene-id",
        "2",
        "-o",
        csv.to_str().unwrap(),
    ]);
    let o = isa(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "scene_id,im_id,obj_id,score,R,t,time");
    assert_eq!(lines.len(), dets.len() + 1);
    let want = if best["category"] == "toilet" {
        "7"
    } else {
        "1"
    };
    assert!(
        lines[1].starts_with(&format!("2,7,{want},")),
        "{}",
        lines[1]
    );
    assert_eq!(text.matches("scene_id").count(), 1);
}

#[test]
fn detect_errors_name_their_cause() {
    let m = detect_model().to_str().unwrap().to_string();
    let (png, k, _, _) = test_png(3, "detect_err.png");
    let [fx, fy, cx, cy] = k_args(&k);
    let p = png.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut a = vec!["detect", p, "-k", &fx, &fy, &cx, &cy, "-q"];
        a.extend_from_slice(extra);
        isa(&a)
    };
    let o = run(&["--model", "nowhere.isa"]);
    expect_exit(&o, 3, &["nowhere.isa"]);
    let o = run(&["--model", model().to_str().unwrap()]); // trained without a box
    expect_exit(&o, 4, &["box"]);
    for bad in ["0,0,0", "1,2"] {
        let o = run(&["--model", &m, "--gravity", bad]);
        expect_exit(&o, 5, &["--gravity"]);
    }
    let o = run(&[
        "--model",
        &m,
        "--shapes",
        tmp("no_shapes_here").to_str().unwrap(),
    ]);
    expect_exit(&o, 3, &["chair.shapes.isl"]);
    // Rankers: a folder without the category's, and a file that is not one.
    let rankers = tmp("rankers_here");
    std::fs::create_dir_all(&rankers).unwrap();
    let _ = std::fs::remove_file(rankers.join("chair.ranker.json")); // an earlier run's
    let r = rankers.to_str().unwrap();
    let o = run(&["--model", &m, "--rankers", r]);
    expect_exit(&o, 3, &["chair.ranker.json"]);
    std::fs::write(rankers.join("chair.ranker.json"), r#"{"format": 1}"#).unwrap();
    let o = run(&["--model", &m, "--rankers", r]);
    expect_exit(&o, 4, &["chair.ranker.json", "not a ranker"]);
    // A boosted ranker (format 2: a stump on the agreement) is read; one whose tree points
    // back at its root is refused, naming the file.
    let stump = r#"{"format": 2, "category": "chair", "features": ["agree"], "mean": [0.0],
        "scale": [1.0], "weights": [0.0], "bias": 0.0, "trees": [{"feature": [0, -1, -1],
        "threshold": [0.5, 0.0, 0.0], "left": [1, 0, 0], "right": [2, 0, 0],
        "value": [0.0, -1.0, 1.0]}]}"#;
    std::fs::write(rankers.join("chair.ranker.json"), stump).unwrap();
    let o = run(&["--model", &m, "--rankers", r]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cycle = stump.replace(r#""left": [1, 0, 0]"#, r#""left": [0, 0, 0]"#);
    std::fs::write(rankers.join("chair.ranker.json"), cycle).unwrap();
    let o = run(&["--model", &m, "--rankers", r]);
    expect_exit(&o, 4, &["chair.ranker.json", "tree 0"]);
    let params = tmp("detect_params.json");
    std::fs::write(&params, r#"{"verify": {"lateral": -1}}"#).unwrap();
    let o = run(&["--model", &m, "--params", params.to_str().unwrap()]);
    expect_exit(&o, 5, &["verify.lateral"]);
}

/// Issue 19: depth in other units with --depth-scale (flag over the camera file), and the
/// wrong-scale and transposed cases: a warning or an error, never a silently wrong pose.
#[test]
fn depth_scales_and_transposed_images_warn_or_fail() {
    let m = model().to_str().unwrap();
    let (depth, k, _, t) = test_view(5);
    let best_t = |o: &Output| nums(&best(o)["t"]);
    // TUM's 5000 per metre: 5 units per millimetre.
    let tum = tmp("tum.png");
    write_png(&tum, 320, 240, depth.iter().map(|&d| d * 5).collect());
    let o = predict_k(m, &tum, &k, &["--stride", "2", "--depth-scale", "0.2"]);
    assert!(
        err_t(&best_t(&o), t) < 0.03 && !stderr(&o).contains("warning"),
        "{}",
        stderr(&o)
    );
    // Without the scale: the pose is 5x too far, and the warning says why.
    let o = predict_k(m, &tum, &k, &["--stride", "2"]);
    let e = stderr(&o);
    assert!(
        e.contains("isa: warning: depth image")
            && e.contains("tum.png")
            && e.contains("depth_scale"),
        "{e}"
    );
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(
        doc["images"][0]["warnings"][0]
            .as_str()
            .unwrap()
            .contains("median 12."),
        "{doc}"
    );
    // A camera file's depth_scale is used; --depth-scale overrides it.
    let cam = tmp("tum-camera.json");
    std::fs::write(&cam, format!(r#"{{"fx": {}, "fy": {}, "cx": {}, "cy": {}, "width": 320, "height": 240, "depth_scale": 0.2}}"#, k.fx, k.fy, k.cx, k.cy)).unwrap();
    let (tum, cam) = (tum.to_str().unwrap(), cam.to_str().unwrap());
    let run = |extra: &[&str]| {
        let mut args = vec!["predict", m, tum, "-c", cam, "--stride", "2"];
        args.extend_from_slice(extra);
        isa(&args)
    };
    assert!(err_t(&best_t(&run(&[])), t) < 0.03);
    let o = run(&["--depth-scale", "1"]);
    assert!(
        stderr(&o).contains("depth_scale 1 mm per unit (given)"),
        "{}",
        stderr(&o)
    );
    // Transposed: an error when the camera states the size, a warning when it cannot.
    let mut tr = vec![0u16; 320 * 240];
    for v in 0..240 {
        for u in 0..320 {
            tr[u * 240 + v] = depth[v * 320 + u];
        }
    }
    let trp = tmp("transposed.png");
    write_png(&trp, 240, 320, tr);
    let o = isa(&["predict", m, trp.to_str().unwrap(), "-c", cam]);
    expect_exit(&o, 4, &["transposed.png", "transposed"]);
    let o = predict_k(m, &trp, &k, &[]);
    expect_exit(&o, 0, &["transposed.png", "transposed"]);
}

/// One row of a BOP results file.
struct BopRow {
    scene_id: u64,
    im_id: u64,
    obj_id: u64,
    _score: f64,
    _r: Vec<f64>,
    t: Vec<f64>,
    time: f64,
}

/// bop_toolkit's `inout.load_bop_results` (bop19), as it reads a file: the header skipped on
/// line 1 only, every other line 7 comma-separated fields (ints, a float, 9 and 3 floats split
/// on whitespace, a float); and its check that all rows of an image share one time.
fn load_bop_results(text: &str) -> Vec<BopRow> {
    let mut out = Vec::new();
    for (i, line) in text.split_inclusive('\n').enumerate() {
        if i == 0 && line.contains("scene_id,im_id,obj_id,score,R,t,time") {
            continue;
        }
        let e: Vec<&str> = line.split(',').collect();
        assert_eq!(e.len(), 7, "line {}: {line:?}", i + 1);
        let floats = |s: &str| -> Vec<f64> {
            s.split_whitespace()
                .map(|v| v.trim().parse().unwrap())
                .collect()
        };
        let (r, t) = (floats(e[4]), floats(e[5]));
        assert_eq!((r.len(), t.len()), (9, 3));
        let int = |s: &str| -> u64 { s.trim().parse().unwrap() };
        out.push(BopRow {
            scene_id: int(e[0]),
            im_id: int(e[1]),
            obj_id: int(e[2]),
            _score: e[3].trim().parse().unwrap(),
            _r: r,
            t,
            time: e[6].trim().parse().unwrap(),
        });
    }
    let mut times = std::collections::HashMap::new();
    for r in &out {
        let t0: f64 = *times.entry((r.scene_id, r.im_id)).or_insert(r.time);
        assert!(
            (t0 - r.time).abs() <= 0.001,
            "image {:?}: times differ",
            (r.scene_id, r.im_id)
        );
    }
    out
}

/// Issue 19: a whole split in one results file (one header), named `METHOD_DATASET-SPLIT.csv`
/// when -o is a folder, obj_id from each image's scene_gt.json, read as bop_toolkit reads it.
#[test]
fn a_bop_split_to_one_results_file_bop_toolkit_reads() {
    let m = model().to_str().unwrap();
    let split = tmp("bopds").join("test");
    let mut truth = Vec::new();
    for (scene_id, view, obj) in [(1u64, 2usize, 3u64), (2, 8, 4)] {
        let dir = split.join(format!("{scene_id:06}"));
        std::fs::create_dir_all(dir.join("depth")).unwrap();
        let (depth, k, _, t) = test_view(view);
        write_png(&dir.join("depth").join("000000.png"), 320, 240, depth);
        let cam = serde_json::json!({"0": {"cam_K": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0], "depth_scale": 1.0}});
        std::fs::write(dir.join("scene_camera.json"), cam.to_string()).unwrap();
        let gt = serde_json::json!({"0": [{"obj_id": obj, "cam_R_m2c": [1,0,0,0,1,0,0,0,1], "cam_t_m2c": [0,0,0]}]});
        std::fs::write(dir.join("scene_gt.json"), gt.to_string()).unwrap();
        truth.push((scene_id, obj, t));
    }
    let out = tmp("bop-out");
    std::fs::create_dir_all(&out).unwrap();
    let (s, o) = (split.to_str().unwrap(), out.to_str().unwrap());
    let run = isa(&[
        "predict", m, "--scene", s, "--format", "bop", "-o", o, "--stride", "2", "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let text = std::fs::read_to_string(out.join("isa_bopds-test.csv")).unwrap();
    assert_eq!(text.matches("scene_id").count(), 1, "{text}");
    let rows = load_bop_results(&text);
    for (scene_id, obj, t) in truth {
        let first = rows
            .iter()
            .find(|r| r.scene_id == scene_id)
            .expect("rows of every scene");
        assert_eq!((first.im_id, first.obj_id), (0, obj));
        let tm: Vec<f64> = first.t.iter().map(|v| v / 1000.0).collect();
        assert!(err_t(&tm, t) < 0.03, "scene {scene_id}: {tm:?} vs {t:?}");
    }
    // No obj_id anywhere (no scene_gt.json, no metadata, no flag): an error, not obj_id 1.
    for d in ["000001", "000002"] {
        std::fs::remove_file(split.join(d).join("scene_gt.json")).unwrap();
    }
    let run = isa(&["predict", m, "--scene", s, "--format", "bop", "-q"]);
    expect_exit(&run, 5, &["obj_id", "--obj-id"]);
    // A file name bop_toolkit would not parse: written, with a warning naming the pattern.
    let f = out.join("results.csv");
    let run = isa(&[
        "predict",
        m,
        "--scene",
        s,
        "--format",
        "bop",
        "--obj-id",
        "9",
        "-o",
        f.to_str().unwrap(),
        "-q",
    ]);
    expect_exit(&run, 0, &["METHOD_DATASET-SPLIT.csv"]);
    assert!(load_bop_results(&std::fs::read_to_string(&f).unwrap())
        .iter()
        .all(|r| r.obj_id == 9));
}

/// Issue 19: the JSON gives the pose also as one 4x4 matrix.
#[test]
fn json_poses_carry_the_4x4_matrix() {
    let m = model().to_str().unwrap();
    let (png, k, _, _) = test_png(5, "pose-view5.png");
    let h = best(&predict_k(m, &png, &k, &["--stride", "2"]));
    let rows: Vec<Vec<f64>> = h["pose"].as_array().unwrap().iter().map(nums).collect();
    let r: Vec<Vec<f64>> = h["R"].as_array().unwrap().iter().map(nums).collect();
    let t = nums(&h["t"]);
    for i in 0..3 {
        assert_eq!(rows[i][..3], r[i][..]);
        assert_eq!(rows[i][3], t[i]);
    }
    assert_eq!(rows[3], vec![0.0, 0.0, 0.0, 1.0]);
}
