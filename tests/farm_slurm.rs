//! The farm on a real one-node Slurm cluster on localhost (munge, slurmctld, slurmd from the
//! Debian packages that `tools/setup.sh --farm` installs), started by `tools/slurm-local.sh`
//! for this test and stopped afterwards (it kills only the daemons it started).
//!
//! One test function, so one cluster serves every case in turn:
//! 1. two wedges with an export stage (`--export-chunk 8 --export-set export.voxel_size=50`),
//!    each interrupted by the scheduler (`scancel --signal=TERM --batch`, standing in for
//!    `--signal=B:TERM@margin` at a time limit: Slurm checks limits only every ~30 s), requeued
//!    and resumed in a later job; every frame byte-identical to a local `nimbus run` (with the
//!    particle caches the export stage makes the simulation write), simulated exactly once; an
//!    export beside the running simulation (which holds the run lock) succeeds and does not
//!    disturb it; every export chunk done, the exports checked by farm_report.json, which says
//!    complete; the contact sheet written;
//! 2. a failing wedge and a killed job step (`kill -9` of the job's nimbus), each failed with its
//!    own note in `farm status`, the resubmit command printed, and `farm resubmit` completing
//!    both from their checkpoints, frames again identical to the local runs;
//! 3. a killed task with the default crash requeue: it comes back by itself and completes; a
//!    task its user cancels is not requeued (failed, "cancelled");
//!    with Blender on PATH, a 2-frame farm with `--render`: each frame rendered to
//!    `render/<shot>.<frame>.png` and counted in the report;
//! 4. the controller unreachable: `farm submit` exits 3 with the remedy, `farm status` exits 3
//!    and still reports the wedges from the farm's files.
//!
//! Skipped, with a note, when not run as root or without the Slurm packages.
mod common;
use common::{blender_available, nimbus, sample, text};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// Port of this test's slurmctld (slurmd: the next one), away from Slurm's default 6817;
/// `NIMBUS_SLURM_PORT` picks another (two clusters on one machine need two ports).
const PORT: u16 = 6937;
/// The export stage of case 1: `--export-chunk 8 --export-set` this, 3 chunks per wedge.
const EXPORT_SET: &str = "export.voxel_size=50";
const VALUES: [&str; 2] = ["0.2", "0.3"];
const FRAMES: u32 = 24;

struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let t = Instant::now();
        let o = Command::new(script())
            .arg("start")
            .arg(dir)
            .env(
                "NIMBUS_SLURM_PORT",
                std::env::var("NIMBUS_SLURM_PORT").unwrap_or(PORT.to_string()),
            )
            .output()
            .unwrap();
        assert!(o.status.success(), "cluster start: {}", text(&o));
        eprintln!("cluster up in {:.1} s", t.elapsed().as_secs_f64());
        Cluster {
            dir: dir.to_path_buf(),
            conf: dir.join("slurm.conf"),
        }
    }

    fn cmd(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn nimbus(&self) -> Command {
        let mut c = nimbus();
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn stop(&self) {
        let _ = Command::new(script()).arg("stop").arg(&self.dir).status();
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        self.stop();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/slurm-local.sh")
}

fn slurm_available() -> Result<(), String> {
    let uid = Command::new("id")
        .arg("-u")
        .output()
        .map_err(|e| e.to_string())?;
    if String::from_utf8_lossy(&uid.stdout).trim() != "0" {
        return Err("not root (slurmd must run as root)".into());
    }
    for p in ["slurmctld", "slurmd", "sbatch", "munged"] {
        let found = std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default())
            .chain([PathBuf::from("/usr/sbin")])
            .any(|d| d.join(p).is_file());
        if !found {
            return Err(format!("{p} not installed (tools/setup.sh --farm)"));
        }
    }
    Ok(())
}

fn fresh_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn wait_for(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
    let t = Instant::now();
    while !done() {
        assert!(t.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn submit(c: &Cluster, config: &Path, farm: &Path, extra: &[&str]) -> Value {
    submit_values(c, config, farm, &VALUES, extra)
}

/// `farm submit` wedged over `physics.heat_source=VALUES`.
fn submit_values(
    c: &Cluster,
    config: &Path,
    farm: &Path,
    values: &[&str],
    extra: &[&str],
) -> Value {
    let o = c
        .nimbus()
        .args(["farm", "submit"])
        .arg(config)
        .args([
            "--wedge",
            &format!("physics.heat_source={}", values.join(",")),
        ])
        .arg("--out")
        .arg(farm)
        .args(extra)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    read_json(&farm.join("farm.json"))
}

fn status(c: &Cluster, farm: &Path) -> Value {
    let o = c
        .nimbus()
        .args(["farm", "status", "--log-format", "json"])
        .arg(farm)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// Frames the wedge's manifest records (0 before it exists).
fn frames_done(run: &Path) -> usize {
    std::fs::read_to_string(run.join("manifest.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .map_or(0, |m| m["frames"].as_array().map_or(0, |a| a.len()))
}

/// Waits until no job of the plan is pending or running any more (a requeued task waits
/// cred_expire + 1 = 11 s on this cluster before it starts again).
fn wait_idle(c: &Cluster, farm: &Path, timeout: Duration) {
    let plan = read_json(&farm.join("farm.json"));
    let ids: Vec<String> = plan["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|j| j["slurm_id"].as_str().map(String::from))
        .collect();
    wait_for("the farm's jobs", timeout, || {
        let o = c
            .cmd("squeue")
            .args([
                "-h",
                "-t",
                "PD,R,CG,CF,RQ",
                "-o",
                "%i",
                "-j",
                &ids.join(","),
            ])
            .output()
            .unwrap();
        o.status.success() && o.stdout.iter().all(|b| b.is_ascii_whitespace())
    });
}

/// Every file of the local run's manifest is byte-identical in the farm's run, and both
/// manifests record the same frames and checksums.
fn assert_same_frames(local: &Path, farm_run: &Path) {
    let a = read_json(&local.join("manifest.json"));
    let b = read_json(&farm_run.join("manifest.json"));
    assert_eq!(b["complete"], true, "{}", farm_run.display());
    assert_eq!(a["frames"], b["frames"], "{}", farm_run.display());
    for f in a["frames"].as_array().unwrap() {
        for file in f["files"].as_array().unwrap() {
            let p = file["path"].as_str().unwrap();
            assert!(
                std::fs::read(local.join(p)).unwrap() == std::fs::read(farm_run.join(p)).unwrap(),
                "{p} differs between the local run and {}",
                farm_run.display()
            );
        }
    }
}

/// The pid of the nimbus process simulating into `run` (found in /proc).
fn nimbus_pid(run: &Path) -> Option<u32> {
    let want = run.to_string_lossy().into_owned();
    for e in std::fs::read_dir("/proc").ok()?.flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(cmd) = std::fs::read(e.path().join("cmdline")) else {
            continue;
        };
        let args: Vec<String> = cmd
            .split(|b| *b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        if args.first().is_some_and(|a| a.ends_with("/nimbus")) && args.contains(&want) {
            return Some(pid);
        }
    }
    None
}

#[test]
fn farm_on_a_real_slurm_cluster() {
    if let Err(why) = slurm_available() {
        // CI installs Slurm (.ci/run: tools/setup.sh --farm): there a missing cluster fails
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but {why}: run tools/setup.sh --farm"
        );
        eprintln!("note: {why}; skipping the Slurm farm test");
        return;
    }
    let t0 = Instant::now();
    let base = fresh_dir("farm_slurm");
    // Under /tmp: munged's socket path must stay short (a Unix socket path holds 108 bytes).
    let cluster_dir = std::env::temp_dir().join(format!("nimbus-slurm-{}", std::process::id()));
    let cluster = Cluster::start(&cluster_dir);

    // The tiny shot, long enough (24 frames, checkpoints every 2) to be interrupted mid-run.
    let config = base.join("shot.yaml");
    let tiny = std::fs::read_to_string(sample("tiny.yaml")).unwrap();
    std::fs::write(&config, tiny.replace("end: 8", &format!("end: {FRAMES}"))).unwrap();
    let local_runs = |name: &str, extra: &[&str]| -> Vec<PathBuf> {
        VALUES
            .iter()
            .map(|v| {
                let out = base.join(format!("{name}_{v}"));
                let o = nimbus()
                    .arg("run")
                    .arg(&config)
                    .arg("--out")
                    .arg(&out)
                    .args(["--set", &format!("physics.heat_source={v}")])
                    .args(extra)
                    .output()
                    .unwrap();
                assert_eq!(o.status.code(), Some(0), "{}", text(&o));
                out
            })
            .collect()
    };
    let locals = local_runs("local", &[]);
    // The export stage makes the farm's simulations write particle caches: compared with local
    // runs that write them too.
    let locals_cached = local_runs("local_cached", &["--set", "export.particles=true"]);

    // 1. Every wedge interrupted by the scheduler once, requeued and resumed; an export stage.
    let farm = base.join("farm_a");
    let plan = submit(
        &cluster,
        &config,
        &farm,
        &["--export-chunk", "8", "--export-set", EXPORT_SET],
    );
    let sim_id = plan["jobs"][0]["slurm_id"].as_str().unwrap().to_string();
    let names: Vec<&str> = plan["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["sim", "export", "report"]);
    let runs: Vec<PathBuf> = plan["wedges"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| farm.join("runs").join(w["name"].as_str().unwrap()))
        .collect();
    let mut signalled = [false; 2];
    wait_for(
        "both wedges to be signalled mid-run",
        Duration::from_secs(120),
        || {
            for (i, run) in runs.iter().enumerate() {
                if signalled[i] {
                    continue;
                }
                let n = frames_done(run);
                assert!(
                    n < FRAMES as usize,
                    "wedge {i} finished before it could be interrupted"
                );
                if n >= 3 {
                    // The simulation holds the run lock exclusively: an export into
                    // exports/<name>/ runs beside it all the same.
                    let holder = std::fs::read_to_string(run.join(".lock")).unwrap();
                    assert!(holder.contains("command run"), "wedge {i}: {holder:?}");
                    let o = nimbus()
                        .arg("export")
                        .arg(run)
                        .args(["--frames", "1-3", "--set", EXPORT_SET])
                        .output()
                        .unwrap();
                    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
                    let o = cluster
                        .cmd("scancel")
                        .args(["--signal=TERM", "--batch", &format!("{sim_id}_{i}")])
                        .output()
                        .unwrap();
                    assert!(o.status.success(), "{}", text(&o));
                    signalled[i] = true;
                }
            }
            signalled.iter().all(|s| *s)
        },
    );
    wait_idle(&cluster, &farm, Duration::from_secs(240));
    let s = status(&cluster, &farm);
    assert_eq!(s["complete"], true, "{s}");
    for (i, w) in s["wedges"].as_array().unwrap().iter().enumerate() {
        assert_eq!(w["state"], "done", "{w}");
        assert!(w["restarts"].as_u64().unwrap() >= 1, "{w}");
        let attempts = std::fs::read_to_string(farm.join(format!("state/sim_{i}.jsonl"))).unwrap();
        let exits: Vec<i64> = attempts
            .lines()
            .map(|l| {
                serde_json::from_str::<Value>(l).unwrap()["exit"]
                    .as_i64()
                    .unwrap()
            })
            .collect();
        assert_eq!(
            exits,
            [130, 0],
            "wedge {i}: interrupted once, then complete"
        );
        assert_same_frames(&locals_cached[i], &runs[i]);
        // no frame simulated (so none written) twice across the jobs
        let log = std::fs::read_to_string(farm.join(format!("logs/sim_{i}.log"))).unwrap();
        let mut seen = vec![0; FRAMES as usize + 1];
        for l in log.lines().filter(|l| l.starts_with('{')) {
            let v: Value = serde_json::from_str(l).unwrap();
            if v["event"] == "frame" {
                seen[v["frame"].as_u64().unwrap() as usize] += 1;
            }
        }
        assert!(seen[1..].iter().all(|n| *n == 1), "wedge {i}: {seen:?}");
        assert!(log.contains("requeued"), "{log}");
    }
    // every export chunk exported its frames (3 per wedge: frames 1-8, 9-16, 17-24)
    for task in 0..6 {
        let log = std::fs::read_to_string(farm.join(format!("logs/export_{task}.log"))).unwrap();
        let (a, b) = (1 + (task % 3) * 8, 8 + (task % 3) * 8);
        assert!(
            log.contains(&format!("--frames {a}-{b} --set {EXPORT_SET}"))
                && log.contains(" done at "),
            "export task {task}: {log}"
        );
    }
    let report = read_json(&farm.join("farm_report.json"));
    assert_eq!(report["complete"], true, "{report}");
    for (i, w) in report["wedges"].as_array().unwrap().iter().enumerate() {
        assert_eq!(w["frames_verified"], FRAMES, "{w}");
        assert_eq!(w["frames_exported"], FRAMES, "{w}");
        assert_eq!(w["bad_files"], serde_json::json!([]), "{w}");
        let dir = PathBuf::from(w["export_dir"].as_str().unwrap());
        assert!(dir.starts_with(runs[i].join("exports")), "{w}");
        let m = read_json(&dir.join("manifest.json"));
        assert_eq!(m["complete"], true, "{}", dir.display());
        assert_eq!(m["voxel_size"], 50.0, "{}", dir.display());
        assert_eq!(
            std::fs::read_dir(dir.join("vdb")).unwrap().count(),
            FRAMES as usize
        );
    }
    let sheet = image::open(farm.join("wedges_contact_sheet.png")).unwrap();
    assert!(sheet.width() > 100 && sheet.height() > 100);
    eprintln!("case 1 done at {:.1} s", t0.elapsed().as_secs_f64());

    // 2. A failing wedge (its run directory holds a foreign file: `nimbus run` exits 2) and a
    //    killed job step (kill -9 of nimbus), with no crash requeues allowed.
    let farm = base.join("farm_b");
    let plan = submit(
        &cluster,
        &config,
        &farm,
        &["--crash-requeues", "0", "--dry-run"],
    );
    let runs: Vec<PathBuf> = plan["wedges"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| farm.join("runs").join(w["name"].as_str().unwrap()))
        .collect();
    std::fs::create_dir_all(&runs[1]).unwrap();
    std::fs::write(runs[1].join("notes.txt"), "not nimbus's").unwrap();
    let o = cluster
        .nimbus()
        .args(["farm", "resubmit"])
        .arg(&farm)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let mut killed = false;
    wait_for(
        "wedge 0 to be killed mid-run",
        Duration::from_secs(120),
        || {
            let n = frames_done(&runs[0]);
            assert!(
                n < FRAMES as usize,
                "wedge 0 finished before it could be killed"
            );
            if n >= 5 {
                if let Some(pid) = nimbus_pid(&runs[0]) {
                    common::kill(pid, "KILL");
                    killed = true;
                }
            }
            killed
        },
    );
    wait_idle(&cluster, &farm, Duration::from_secs(120));
    let s = status(&cluster, &farm);
    assert_eq!(s["complete"], false, "{s}");
    let w = &s["wedges"];
    assert_eq!(w[0]["state"], "failed", "{s}");
    assert!(
        w[0]["note"]
            .as_str()
            .unwrap()
            .contains("killed by signal 9"),
        "{s}"
    );
    assert_eq!(w[1]["state"], "failed", "{s}");
    assert!(w[1]["note"].as_str().unwrap().contains("exit 2"), "{s}");
    let resubmit = s["resubmit_command"].as_str().unwrap().to_string();
    assert!(resubmit.starts_with("nimbus farm resubmit "), "{resubmit}");
    let human = cluster
        .nimbus()
        .args(["farm", "status"])
        .arg(&farm)
        .output()
        .unwrap();
    assert!(text(&human).contains(&resubmit), "{}", text(&human));
    assert_eq!(read_json(&farm.join("farm_report.json"))["complete"], false);
    let kept = frames_done(&runs[0]);
    assert!(kept >= 5, "the killed wedge kept its frames ({kept})");

    // The printed command brings both back: the killed one resumes from its checkpoint.
    std::fs::remove_file(runs[1].join("notes.txt")).unwrap();
    let o = cluster
        .nimbus()
        .args(["farm", "resubmit"])
        .arg(&farm)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    wait_idle(&cluster, &farm, Duration::from_secs(120));
    let s = status(&cluster, &farm);
    assert_eq!(s["complete"], true, "{s}");
    for i in 0..2 {
        assert_same_frames(&locals[i], &runs[i]);
    }
    let log = std::fs::read_to_string(farm.join("logs/sim_0.log")).unwrap();
    assert!(log.contains("nimbus resume"), "wedge 0 resumed: {log}");
    eprintln!("case 2 done at {:.1} s", t0.elapsed().as_secs_f64());

    // A killed task with a crash requeue allowed (the default, 1) comes back by itself.
    let farm = base.join("farm_crash");
    let plan = submit_values(&cluster, &config, &farm, &VALUES[..1], &[]);
    let run = farm
        .join("runs")
        .join(plan["wedges"][0]["name"].as_str().unwrap());
    let mut killed = false;
    wait_for(
        "the wedge to be killed mid-run",
        Duration::from_secs(120),
        || {
            let n = frames_done(&run);
            assert!(
                n < FRAMES as usize,
                "the wedge finished before it could be killed"
            );
            if n >= 5 {
                if let Some(pid) = nimbus_pid(&run) {
                    common::kill(pid, "KILL");
                    killed = true;
                }
            }
            killed
        },
    );
    wait_idle(&cluster, &farm, Duration::from_secs(120));
    let s = status(&cluster, &farm);
    assert_eq!(s["complete"], true, "{s}");
    assert_eq!(s["wedges"][0]["last_exit"], 0, "{s}");
    let attempts = std::fs::read_to_string(farm.join("state/sim_0.jsonl")).unwrap();
    assert!(
        attempts.lines().next().unwrap().contains("\"exit\":137"),
        "{attempts}"
    );
    assert_same_frames(&locals[0], &run);
    eprintln!(
        "crash requeue case done at {:.1} s",
        t0.elapsed().as_secs_f64()
    );

    // A task its user cancels (scancel) is not requeued: failed, with the resubmit command.
    let farm = base.join("farm_cancel");
    let plan = submit_values(&cluster, &config, &farm, &VALUES[..1], &[]);
    let id = plan["jobs"][0]["slurm_id"].as_str().unwrap().to_string();
    let run = farm
        .join("runs")
        .join(plan["wedges"][0]["name"].as_str().unwrap());
    wait_for("the wedge to start", Duration::from_secs(120), || {
        let n = frames_done(&run);
        assert!(
            n < FRAMES as usize,
            "the wedge finished before it could be cancelled"
        );
        n >= 3
    });
    let o = cluster.cmd("scancel").arg(&id).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    wait_idle(&cluster, &farm, Duration::from_secs(120));
    let s = status(&cluster, &farm);
    let w = &s["wedges"][0];
    assert_eq!(w["state"], "failed", "{s}");
    assert_eq!(w["restarts"], 0, "{s}");
    assert!(w["note"].as_str().unwrap().contains("cancelled"), "{s}");
    assert!(s["resubmit_command"].is_string(), "{s}");
    eprintln!("cancel case done at {:.1} s", t0.elapsed().as_secs_f64());

    // The render stage: a 2-frame farm with --render (Blender renders each frame).
    if blender_available() {
        let short = base.join("short.yaml");
        std::fs::write(&short, tiny.replace("end: 8", "end: 2")).unwrap();
        let farm = base.join("farm_render");
        let o = cluster
            .nimbus()
            .args(["farm", "submit"])
            .arg(&short)
            .arg("--render")
            .arg("--out")
            .arg(&farm)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(0), "{}", text(&o));
        wait_idle(&cluster, &farm, Duration::from_secs(180));
        let report = read_json(&farm.join("farm_report.json"));
        assert_eq!(report["complete"], true, "{report}");
        assert_eq!(report["wedges"][0]["frames_rendered"], 2, "{report}");
        for f in [1, 2] {
            let png = farm.join(format!("runs/tiny_w0/render/tiny.{f:04}.png"));
            let img = image::open(&png).unwrap();
            assert_eq!((img.width(), img.height()), (320, 240), "{}", png.display());
        }
        eprintln!("render case done at {:.1} s", t0.elapsed().as_secs_f64());
    } else {
        eprintln!("note: blender not on PATH, skipping the farm's render case");
    }

    // 4. The controller unreachable.
    cluster.stop();
    let o = cluster
        .nimbus()
        .args(["farm", "submit"])
        .arg(&config)
        .arg("--out")
        .arg(base.join("farm_c"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("Unable to contact slurm controller"), "{err}");
    assert!(err.contains("tools/slurm-local.sh"), "{err}");
    // farm status still answers from the farm's files, and says the queue is unreachable.
    let o = cluster
        .nimbus()
        .args(["farm", "status", "--log-format", "json"])
        .arg(base.join("farm_a"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(
        s["scheduler_error"].as_str().unwrap().contains("squeue"),
        "{s}"
    );
    assert!(
        s["wedges"]
            .as_array()
            .unwrap()
            .iter()
            .all(|w| w["state"] == "done"),
        "{s}"
    );
    eprintln!("all done in {:.1} s", t0.elapsed().as_secs_f64());
}
