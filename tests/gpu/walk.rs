//! `coherent walk`: the report files, their fields, the scaling table, with validation on.

use std::process::Command;

fn tempdir(name: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(&format!("walk-{name}"))
}

#[test]
fn walk_writes_csv_json_and_plots() {
    let dir = tempdir("files");
    let out = Command::new(env!("CARGO_BIN_EXE_coherent"))
        .args([
            "walk",
            "--scene",
            "city",
            "--scale",
            "0.05",
            "--path",
            "street",
            "--frames",
            "6",
            "--warmup",
            "2",
            "--algorithms",
            "vfc,stop-and-wait,chc,chcpp,oracle",
        ])
        .args([
            "--size",
            "96x64",
            "--validation",
            "--out",
            dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("x oracle"),
        "summary table printed: {stdout}"
    );

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let keys: Vec<&str> = json
        .as_object()
        .unwrap()
        .keys()
        .map(|k| k.as_str())
        .collect();
    for k in [
        "scene",
        "objects",
        "triangles",
        "device",
        "size",
        "frames",
        "algorithms",
        "repeats",
        "ratios",
    ] {
        assert!(keys.contains(&k), "summary.json has {k}: {keys:?}");
    }
    assert_eq!(json["repeats"], 1);
    let chcpp_vs_vfc = &json["ratios"]["chcpp"]["vs_vfc"];
    assert!(chcpp_vs_vfc["median"].as_f64().unwrap() > 0.0);
    assert!(chcpp_vs_vfc["min"].as_f64().unwrap() <= chcpp_vs_vfc["max"].as_f64().unwrap());
    assert_eq!(json["frames"], 6);
    assert_eq!(json["size"], "96x64");
    let algs = json["algorithms"].as_object().unwrap();
    let mut names: Vec<&str> = algs.keys().map(|k| k.as_str()).collect();
    names.sort();
    assert_eq!(names, ["chc", "chcpp", "oracle", "stop-and-wait", "vfc"]);
    let fields = [
        "frame_ms_median",
        "frame_ms_p95",
        "gpu_ms_median",
        "stall_ms_median",
        "cpu_ms_median",
        "queries_median",
        "wasted_queries_median",
        "state_changes_median",
        "pipeline_binds_median",
        "draw_calls_median",
        "object_draws_median",
        "query_draws_median",
        "triangles_median",
        "submits_median",
        "objects_median",
        "predicated_draws_median",
        "predicated_taken_median",
        "predicated_taken_max",
        "predicate_resolves_median",
        "tested_parts_median",
    ];
    for (name, a) in algs {
        let mut got: Vec<&str> = a.as_object().unwrap().keys().map(|k| k.as_str()).collect();
        got.sort();
        let mut want = fields.to_vec();
        want.sort();
        assert_eq!(got, want, "{name}");
    }
    assert_eq!(algs["vfc"]["queries_median"], 0.0);
    // The CPU's part of a frame is measured and never more than the frame.
    for (name, a) in algs {
        let (cpu, frame) = (
            a["cpu_ms_median"].as_f64().unwrap(),
            a["frame_ms_median"].as_f64().unwrap(),
        );
        assert!(
            cpu > 0.0 && cpu <= frame,
            "{name}: cpu {cpu} ms, frame {frame} ms"
        );
    }
    assert!(algs["chcpp"]["queries_median"].as_f64().unwrap() > 0.0);

    let csv = std::fs::read_to_string(dir.join("frames.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "algorithm,frame,repeat,frame_ms,gpu_ms,stall_ms,queries,wasted_queries,state_changes,pipeline_binds,draw_calls,object_draws,query_draws,triangles,objects,submits,missed_objects,missed_pixels,extra_objects,extra_predicated_objects,mover_draws,predicated_draws,predicated_taken,predicate_resolves,multiqueries,visible_leaf_queries,predicated_queries,tested_parts,flag_tests,cpu_ms"
    );
    assert_eq!(lines.count(), 6 * 5);
    for png in ["frametime.png", "counts.png"] {
        let len = std::fs::metadata(dir.join(png)).unwrap().len();
        assert!(len > 20_000, "{png} is a real plot ({len} bytes)");
    }
}

#[test]
fn walk_scaling_table_and_bad_flags() {
    let dir = tempdir("scale");
    let out = Command::new(env!("CARGO_BIN_EXE_coherent"))
        .args([
            "walk", "--scene", "parking", "--scale", "0.1,0.3", "--frames", "3", "--warmup", "0",
        ])
        .args([
            "--size",
            "64x48",
            "--algorithms",
            "vfc,chcpp",
            "--out",
            dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = std::fs::read_to_string(dir.join("scaling.txt")).unwrap();
    assert!(table.contains("vfc") && table.contains("chcpp"), "{table}");
    assert!(
        dir.join("scale_0.1/summary.json").exists() && dir.join("scale_0.3/summary.json").exists()
    );

    for args in [
        vec!["--algorithms", "vfc,warp"],
        vec!["--frames", "0"],
        vec!["--disable", "nothing"],
        // Multiqueries need the i-queue: the combination is refused, not silently changed.
        vec!["--disable", "batching"],
        vec!["--repeat", "0"],
        vec!["--split-ratio", "inf"],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_coherent"))
            .args(["walk", "--scene", "cornell", "--size", "32x32"])
            .args(&args)
            .arg("--out")
            .arg(&dir)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.starts_with("error:") && err.trim().lines().count() == 1,
            "{args:?}: {err}"
        );
    }
}

#[test]
fn walk_repeats_report_ratio_spread() {
    let dir = tempdir("repeat");
    let out = Command::new(env!("CARGO_BIN_EXE_coherent"))
        .args([
            "walk", "--scene", "parking", "--scale", "0.1", "--frames", "3",
        ])
        .args(["--warmup", "0", "--repeat", "2", "--size", "64x48"])
        .args(["--algorithms", "vfc,chcpp,oracle", "--pixel-threshold", "2"])
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("over 2 repeat(s)"), "{stdout}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(json["repeats"], 2);
    assert_eq!(json["frames"], 3);
    let r = &json["ratios"]["chcpp"]["vs_oracle"];
    let (lo, med, hi) = (
        r["min"].as_f64().unwrap(),
        r["median"].as_f64().unwrap(),
        r["max"].as_f64().unwrap(),
    );
    assert!(lo <= med && med <= hi && lo > 0.0, "{r}");
    let csv = std::fs::read_to_string(dir.join("frames.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 3 * 3 * 2);
    assert!(csv.lines().any(|l| l.starts_with("chcpp,2,1,")));
}

/// The plots' font is looked for before a walk or a GI run starts: a missing one fails at once
/// with one line that names it (and `COHERENT_FONT`), before any frame and any file.
#[test]
fn walk_and_gi_refuse_a_missing_font_before_they_start() {
    let dir = tempdir("font");
    for args in [
        vec![
            "walk", "--scene", "cornell", "--frames", "2", "--size", "32x32",
        ],
        vec![
            "gi", "--scene", "cornell", "--frames", "2", "--size", "32x32",
        ],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_coherent"))
            .args(&args)
            .arg("--out")
            .arg(dir.join(args[0]))
            .env("COHERENT_FONT", dir.join("no-such-font.ttf"))
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.starts_with("error: font not found")
                && err.contains("COHERENT_FONT")
                && err.trim().lines().count() == 1,
            "{args:?}: {err}"
        );
        assert!(!dir.join(args[0]).exists(), "{args:?} wrote files");
    }
}

/// `coherent info` names the device and every optional feature coherent uses, and where the
/// plots' font is (or that it is missing, which no other command needs).
#[test]
fn info_names_the_device_its_features_and_the_plots_font() {
    let run = |font: Option<&str>| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_coherent"));
        cmd.arg("info");
        if let Some(f) = font {
            cmd.env("COHERENT_FONT", f);
        }
        let out = crate::common::on_test_device(&mut cmd).output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    let text = run(None);
    for label in [
        "device:",
        "driver:",
        "Vulkan version:",
        "chosen because:",
        "hiz needs:",
        "gi shadow maps:",
        "oracle-box:",
        "predicated:",
        "features used:",
        "plots font:",
    ] {
        assert_eq!(
            text.lines().filter(|l| l.starts_with(label)).count(),
            1,
            "{label}\n{text}"
        );
    }
    let font = text.lines().find(|l| l.starts_with("plots font:")).unwrap();
    let path = font["plots font:".len()..].trim();
    assert!(std::path::Path::new(path).is_file(), "{font}");
    let missing = run(Some("/no/such/font.ttf"));
    assert!(
        missing.contains(
            "plots font:      font not found: /no/such/font.ttf (named by COHERENT_FONT)"
        ),
        "{missing}"
    );
}
