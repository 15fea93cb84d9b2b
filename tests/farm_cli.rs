//! `nimbus farm submit` without a cluster: the plan a dry run writes, wedge values refused before
//! anything is written or submitted (exit 2, FILE:LINE:COL and key), and sbatch missing (exit 3
//! with the remedy). The farm on a real Slurm cluster is tests/farm_slurm.rs.
mod common;
use common::{nimbus, sample, text};
use std::path::{Path, PathBuf};

fn fresh_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A PATH with the usual tools but no Slurm client: an empty directory plus /bin for bash.
fn path_without_sbatch(base: &Path) -> std::ffi::OsString {
    let empty = base.join("empty-bin");
    std::fs::create_dir_all(&empty).unwrap();
    std::env::join_paths([empty]).unwrap()
}

#[test]
fn dry_run_writes_the_plan_and_submits_nothing() {
    let base = fresh_dir("farm_dry_run");
    let farm = base.join("farm");
    let o = nimbus()
        .args(["farm", "submit"])
        .arg(sample("tiny.yaml"))
        .args(["--wedge", "physics.heat_source=0.2,0.3"])
        .args(["--wedge", "seed=3,4"])
        .args(["--time-limit", "10:00", "--partition", "main", "--dry-run"])
        .arg("--out")
        .arg(&farm)
        // a dry run needs no Slurm at all
        .env("PATH", path_without_sbatch(&base))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("sbatch --parsable --array=0-3"), "{stdout}");
    assert!(stdout.contains("dry run: nothing submitted"), "{stdout}");

    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(farm.join("farm.json")).unwrap()).unwrap();
    let wedges = plan["wedges"].as_array().unwrap();
    assert_eq!(wedges.len(), 4);
    // the first --wedge varies slowest; names carry the values
    assert_eq!(wedges[0]["name"], "tiny_w0_heat_source-0.2_seed-3");
    assert_eq!(wedges[3]["name"], "tiny_w3_heat_source-0.3_seed-4");
    assert_eq!(
        wedges[1]["values"],
        serde_json::json!([["physics.heat_source", "0.2"], ["seed", "4"]])
    );
    assert_eq!(wedges[3]["run_dir"], "runs/tiny_w3_heat_source-0.3_seed-4");
    let farm_abs = farm.canonicalize().unwrap();
    assert_eq!(
        wedges[3]["command"],
        format!(
            "nimbus run {0}/shot.yaml --out {0}/runs/tiny_w3_heat_source-0.3_seed-4 --set physics.heat_source=0.3 --set seed=4",
            farm_abs.display()
        )
    );
    let jobs = plan["jobs"].as_array().unwrap();
    let names: Vec<&str> = jobs.iter().map(|j| j["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["sim", "report"]);
    assert!(jobs.iter().all(|j| j["slurm_id"].is_null()));
    assert_eq!(jobs[0]["tasks"], serde_json::json!([0, 1, 2, 3]));
    assert_eq!(
        jobs[1]["depends_on"],
        serde_json::json!([{"job": "sim", "kind": "afterany"}])
    );
    assert_eq!(plan["slurm"]["time_limit"], "10:00");

    let sim = std::fs::read_to_string(farm.join("jobs/sim.sbatch")).unwrap();
    for line in [
        "#SBATCH --requeue",
        "#SBATCH --signal=B:TERM@120",
        "#SBATCH --time=10:00",
        "#SBATCH --partition=main",
        "--set physics.heat_source=0.3 --set seed=4",
        "scontrol requeue",
    ] {
        assert!(sim.contains(line), "sim.sbatch lacks {line:?}:\n{sim}");
    }
    // the script is valid bash
    let syntax = std::process::Command::new("bash")
        .arg("-n")
        .arg(farm.join("jobs/sim.sbatch"))
        .output()
        .unwrap();
    assert!(syntax.status.success(), "{}", text(&syntax));
    // the jobs read a copy of the config
    assert_eq!(
        std::fs::read(farm.join("shot.yaml")).unwrap(),
        std::fs::read(sample("tiny.yaml")).unwrap()
    );
    // the same directory twice is refused
    let again = nimbus()
        .args(["farm", "submit"])
        .arg(sample("tiny.yaml"))
        .args(["--dry-run", "--out"])
        .arg(&farm)
        .output()
        .unwrap();
    assert_eq!(again.status.code(), Some(2), "{}", text(&again));
    assert!(
        text(&again).contains("already holds a farm"),
        "{}",
        text(&again)
    );
}

/// A shot with a pre-roll: the plan records its frames (each simulation task simulates them
/// before frame 1), and the dry run says so.
#[test]
fn dry_run_plans_the_preroll() {
    let base = fresh_dir("farm_dry_run_preroll");
    let farm = base.join("farm");
    let yaml = base.join("tiny_preroll.yaml");
    let tiny = std::fs::read_to_string(sample("tiny.yaml")).unwrap();
    // 12 s of pre-roll at tiny's 5 s frames: 3 frames
    let shot = tiny.replacen(
        "  frame_seconds: 5.0\n",
        "  frame_seconds: 5.0\n  preroll: 12\n",
        1,
    );
    assert_ne!(
        shot, tiny,
        "samples/tiny.yaml changed: put the pre-roll elsewhere"
    );
    std::fs::write(&yaml, shot).unwrap();
    let o = nimbus()
        .args(["farm", "submit"])
        .arg(&yaml)
        .args(["--time-limit", "10:00", "--dry-run", "--out"])
        .arg(&farm)
        .env("PATH", path_without_sbatch(&base))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(farm.join("farm.json")).unwrap()).unwrap();
    assert_eq!(plan["preroll_frames"], 3, "{plan}");
    assert_eq!(plan["frame_start"], 1);
    // status reads it from the plan, without a scheduler to ask
    let status = nimbus()
        .args(["farm", "status", "--log-format", "json"])
        .arg(&farm)
        .env("PATH", path_without_sbatch(&base))
        .output()
        .unwrap();
    let s: serde_json::Value =
        serde_json::from_slice(&status.stdout).unwrap_or_else(|e| panic!("{e}: {}", text(&status)));
    assert_eq!(s["preroll_frames"], 3, "{s}");
    let status = nimbus()
        .args(["farm", "status"])
        .arg(&farm)
        .env("PATH", path_without_sbatch(&base))
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&status.stdout);
    assert!(
        out.contains("frames 1..=8, after a pre-roll of 3 frames"),
        "{}",
        text(&status)
    );
}

#[test]
fn invalid_wedge_values_and_flags_are_refused_before_anything_is_written() {
    let base = fresh_dir("farm_bad_wedge");
    let cases: [(&[&str], &str); 7] = [
        // the file sets heat_source at line 16: the error points there
        (
            &["--wedge", "physics.heat_source=0.2,30"],
            "tiny.yaml:16:3: physics.heat_source: --wedge value \"30\" (wedge tiny_w1_heat_source-30): expected a number in [0, 10], got 30",
        ),
        // a key the file leaves at its default is named without a line
        (
            &["--wedge", "physics.buoyancy=x"],
            "tiny.yaml: --wedge physics.buoyancy: value \"x\" (wedge tiny_w0_buoyancy-x): expected a number",
        ),
        (&["--wedge", "physics.heat_sorce=0.1"], "unknown key \"heat_sorce\""),
        (&["--wedge", "seed"], "--wedge \"seed\": expected KEY.PATH=V1,V2,..."),
        (&["--wedge", "seed=1", "--wedge", "seed=2"], "the key is wedged twice"),
        // a time limit that leaves no room for the stop-and-checkpoint margin
        (
            &["--time-limit", "2"],
            "--time-limit 2 (120 s) must be longer than --signal-margin (120 s)",
        ),
        (&["--time-limit", "1h"], "--time-limit \"1h\": expected minutes"),
    ];
    for (args, want) in cases {
        let farm = base.join("farm");
        let o = nimbus()
            .args(["farm", "submit"])
            .arg(sample("tiny.yaml"))
            .args(args)
            .arg("--out")
            .arg(&farm)
            .env("PATH", path_without_sbatch(&base))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(want), "{args:?}: want {want:?} in:\n{err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
        assert!(!farm.exists(), "{args:?}: the farm directory was written");
    }
}

#[test]
fn sbatch_missing_is_a_runtime_error_with_the_remedy() {
    let base = fresh_dir("farm_no_sbatch");
    let farm = base.join("farm");
    let o = nimbus()
        .args(["farm", "submit"])
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&farm)
        .env("PATH", path_without_sbatch(&base))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("sbatch not found on PATH"), "{err}");
    assert!(err.contains("tools/setup.sh --farm"), "{err}");
    // the plan is whole and says nothing was submitted
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(farm.join("farm.json")).unwrap()).unwrap();
    assert!(plan["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .all(|j| j["slurm_id"].is_null()));
}

#[test]
fn dry_run_plans_the_export_stage() {
    let base = fresh_dir("farm_dry_run_export");
    let farm = base.join("farm");
    // tiny.yaml: frames 1-8, so chunks of 3 frames are 1-3, 4-6, 7-8
    let o = nimbus()
        .args(["farm", "submit"])
        .arg(sample("tiny.yaml"))
        .args(["--wedge", "physics.heat_source=0.2,0.3"])
        .args([
            "--export-chunk",
            "3",
            "--export-set",
            "export.voxel_size=50",
        ])
        .args(["--export-name", "coarse", "--dry-run", "--out"])
        .arg(&farm)
        .env("PATH", path_without_sbatch(&base))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    let farm_abs = farm.canonicalize().unwrap();
    // tasks wedge * chunks + chunk: wedge 0 is 0-2, wedge 1 is 3-5; after the simulation started
    assert!(
        stdout.contains(&format!(
            "export: sbatch --parsable --array=0-5 '--export=ALL,NIMBUS_FARM_SIM_JOB=<id>' '--dependency=after:<id>' {}/jobs/export.sbatch",
            farm_abs.display()
        )),
        "{stdout}"
    );
    assert!(
        stdout.contains("--dependency=afterany:<id>,afterany:<id>"),
        "{stdout}"
    );

    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(farm.join("farm.json")).unwrap()).unwrap();
    assert_eq!(
        plan["export"],
        serde_json::json!({"chunk": 3, "sets": ["export.voxel_size=50"], "name": "coarse"})
    );
    let jobs = plan["jobs"].as_array().unwrap();
    let names: Vec<&str> = jobs.iter().map(|j| j["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["sim", "export", "report"]);
    assert_eq!(jobs[1]["kind"], "export");
    assert_eq!(jobs[1]["tasks"], serde_json::json!([0, 1]));
    assert_eq!(
        jobs[1]["depends_on"],
        serde_json::json!([{"job": "sim", "kind": "after"}])
    );
    assert_eq!(
        jobs[2]["depends_on"],
        serde_json::json!([{"job": "sim", "kind": "afterany"}, {"job": "export", "kind": "afterany"}])
    );
    // the simulation writes the particle caches nimbus export splats
    let w1 = &plan["wedges"][1];
    assert!(
        w1["command"]
            .as_str()
            .unwrap()
            .ends_with("--set physics.heat_source=0.3 --set export.particles=true"),
        "{w1}"
    );
    let sim = std::fs::read_to_string(farm.join("jobs/sim.sbatch")).unwrap();
    assert!(
        sim.contains("--set physics.heat_source=0.3 --set export.particles=true"),
        "{sim}"
    );
    let export = std::fs::read_to_string(farm.join("jobs/export.sbatch")).unwrap();
    for line in [
        "#SBATCH --requeue",
        "START=1\nEND=8\nCHUNK=3\nCHUNKS=3\n",
        "EXPORT=(--set export.voxel_size=50 --name coarse)",
        "\"$NIMBUS\" export \"$RUN\" --frames \"$A-$B\" \"${EXPORT[@]}\"",
        "scontrol requeue \"$ME\"",
        "left the queue",
    ] {
        assert!(
            export.contains(line),
            "export.sbatch lacks {line:?}:\n{export}"
        );
    }
    let syntax = std::process::Command::new("bash")
        .arg("-n")
        .arg(farm.join("jobs/export.sbatch"))
        .output()
        .unwrap();
    assert!(syntax.status.success(), "{}", text(&syntax));
    // the chunk arithmetic of the script: task 5 is wedge 1, frames 7-8
    let head: String = export
        .lines()
        .filter(|l| {
            [
                "START=", "END=", "CHUNK=", "CHUNKS=", "WEDGE=", "C=", "A=", "B=", "if [ $B",
            ]
            .iter()
            .any(|p| l.starts_with(p))
        })
        .collect::<Vec<_>>()
        .join("\n");
    let o = std::process::Command::new("bash")
        .arg("-c")
        .arg(format!("{head}\necho $WEDGE $A $B"))
        .env("SLURM_ARRAY_TASK_ID", "5")
        .output()
        .unwrap();
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "1 7 8", "{head}");

    // refused before anything is written (exit 2)
    let cases: [(&[&str], &str); 6] = [
        (
            &["--export-chunk", "3"],
            "--export-chunk needs at least one --export-set",
        ),
        (
            &["--export-set", "export.voxel_size=50"],
            "--export-set and --export-name need --export-chunk N",
        ),
        (
            &[
                "--export-chunk",
                "0",
                "--export-set",
                "export.voxel_size=50",
            ],
            "--export-chunk 0",
        ),
        (
            &["--export-chunk", "3", "--export-set", "seed=4"],
            "--export-set seed: nimbus export changes export.* keys only",
        ),
        (
            &[
                "--export-chunk",
                "3",
                "--export-set",
                "export.particles=false",
            ],
            "--export-set export.particles: nimbus export changes export.* keys only",
        ),
        // the run's own settings: the simulation writes those files itself
        (
            &[
                "--export-chunk",
                "3",
                "--export-set",
                "export.voxel_size=25",
            ],
            "leaves the export settings of wedge tiny_w0 as they are",
        ),
    ];
    for (args, want) in cases {
        let farm = base.join("refused");
        let o = nimbus()
            .args(["farm", "submit"])
            .arg(sample("tiny.yaml"))
            .args(args)
            .args(["--dry-run", "--out"])
            .arg(&farm)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(want), "{args:?}: want {want:?} in:\n{err}");
        assert!(!farm.exists(), "{args:?}: the farm directory was written");
    }
}

/// The export script's waiting, without a cluster: `squeue` and `scontrol` stand-ins on PATH.
#[test]
fn export_task_requeues_while_its_simulation_waits_and_gives_up_when_it_is_gone() {
    let base = fresh_dir("farm_export_script");
    let farm = base.join("farm");
    let o = nimbus()
        .args(["farm", "submit"])
        .arg(sample("tiny.yaml"))
        .args(["--wedge", "physics.heat_source=0.2,0.3"])
        .args([
            "--export-chunk",
            "3",
            "--export-set",
            "export.voxel_size=50",
        ])
        .args(["--dry-run", "--out"])
        .arg(&farm)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(farm.join("farm.json")).unwrap()).unwrap();
    let run = farm.join(plan["wedges"][0]["run_dir"].as_str().unwrap());
    std::fs::create_dir_all(&run).unwrap();
    // frames 1 and 2 recorded; task 0 (wedge 0, frames 1-3) still needs frame 3
    std::fs::write(
        run.join("manifest.json"),
        "{\n  \"frames\": [\n    {\n      \"frame\": 1,\n      \"files\": []\n    },\n    {\n      \"frame\": 2,\n      \"files\": []\n    }\n  ]\n}\n",
    )
    .unwrap();
    let bin = base.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let calls = base.join("calls");
    let fake = |name: &str, body: &str| {
        let p = bin.join(name);
        std::fs::write(
            &p,
            format!(
                "#!/bin/bash\necho \"{name} $*\" >>{}\n{body}\n",
                calls.display()
            ),
        )
        .unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    };
    fake(
        "scontrol",
        "case $1 in show) echo 'JobId=8 JobState=RUNNING' ;; requeue) exit 0 ;; esac",
    );
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let task = |sim_state: &str| {
        fake("squeue", &format!("echo {sim_state}"));
        let _ = std::fs::remove_file(&calls);
        let o = std::process::Command::new("bash")
            .arg(farm.join("jobs/export.sbatch"))
            .env("PATH", &path)
            .env("SLURM_ARRAY_JOB_ID", "8")
            .env("SLURM_ARRAY_TASK_ID", "0")
            .env("NIMBUS_FARM_SIM_JOB", "7")
            .output()
            .unwrap();
        (o, std::fs::read_to_string(&calls).unwrap_or_default())
    };
    // the simulation is back in the queue: the export task gives its node back
    let (o, calls_made) = task("PENDING");
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(
        calls_made.contains("squeue -h -t all -j 7_0 -o %T"),
        "{calls_made}"
    );
    assert!(calls_made.contains("scontrol requeue 8_0"), "{calls_made}");
    assert!(
        text(&o).contains("simulation 7_0 is PENDING; requeued"),
        "{}",
        text(&o)
    );
    // the simulation has left the queue without frame 3: it gives up
    let (o, calls_made) = task("COMPLETED");
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    assert!(!calls_made.contains("requeue"), "{calls_made}");
    assert!(
        text(&o).contains("simulation task 7_0 left the queue (COMPLETED) without frames 1-3"),
        "{}",
        text(&o)
    );
}

#[test]
fn backend_values_and_backend_only_flags_are_checked() {
    let base = fresh_dir("farm_backend_flags");
    let cases: [(&[&str], &str); 4] = [
        (
            &["--backend", "pbs"],
            "--backend \"pbs\": expected slurm or openjd",
        ),
        (
            &["--run-local"],
            "--run-local runs an Open Job Description template: it needs --backend openjd",
        ),
        (
            &["--backend", "openjd", "--partition", "main"],
            "--partition is a Slurm setting",
        ),
        (
            &["--backend", "openjd", "--signal-margin", "601"],
            "--signal-margin 601: with --backend openjd it is the cancelation notice",
        ),
    ];
    for (args, want) in cases {
        let farm = base.join("farm");
        let o = nimbus()
            .args(["farm", "submit"])
            .arg(sample("tiny.yaml"))
            .args(args)
            .arg("--out")
            .arg(&farm)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(stderr.contains(want), "{args:?}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "one line: {stderr}");
        assert!(!farm.exists(), "{args:?} wrote {}", farm.display());
    }
}

/// The OpenJD template of a 2-wedge shot with export chunks and a time limit, without the
/// openjd CLI (tests/farm_openjd.rs checks and runs it with the real one).
#[test]
fn openjd_backend_writes_the_plan_as_a_job_template() {
    let base = fresh_dir("farm_openjd_template");
    let farm = base.join("farm");
    let o = nimbus()
        .args(["farm", "submit", "--backend", "openjd"])
        .arg(sample("tiny.yaml"))
        .args(["--wedge", "physics.heat_source=0.2,0.3"])
        .args([
            "--export-chunk",
            "3",
            "--export-set",
            "export.voxel_size=50",
        ])
        .args(["--time-limit", "10:00", "--signal-margin", "30"])
        .arg("--out")
        .arg(&farm)
        // writing the template needs neither Slurm nor openjd
        .env("PATH", path_without_sbatch(&base))
        .env_remove("NIMBUS_OPENJD")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let farm = farm.canonicalize().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains(&format!(
            "wrote the Open Job Description template: {}",
            farm.join("template.json").display()
        )),
        "{stdout}"
    );
    assert!(stdout.contains("openjd check "), "{stdout}");

    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(farm.join("template.json")).unwrap())
            .unwrap();
    assert_eq!(t["specificationVersion"], "jobtemplate-2023-09");
    let names: Vec<&str> = t["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["Simulation", "Export", "Report"]);
    let params = t["parameterDefinitions"].as_array().unwrap();
    assert_eq!(params[0]["name"], "FarmDir");
    assert_eq!(params[0]["default"], ".");
    let sim = &t["steps"][0];
    assert_eq!(
        sim["parameterSpace"]["taskParameterDefinitions"],
        serde_json::json!([{"name": "Wedge", "type": "INT", "range": [0, 1]}])
    );
    let on_run = &sim["script"]["actions"]["onRun"];
    // the time limit less the notice, then SIGTERM, 30 s to checkpoint
    assert_eq!(on_run["timeout"], 570);
    assert_eq!(
        on_run["cancelation"],
        serde_json::json!({"mode": "NOTIFY_THEN_TERMINATE", "notifyPeriodInSeconds": 30})
    );
    let script = sim["script"]["embeddedFiles"][0]["data"].as_str().unwrap();
    assert!(
        script.contains(
            "1) RUN=\"$FARM\"/runs/tiny_w1_heat_source-0.3; SETS=(--set physics.heat_source=0.3 --set export.particles=true)"
        ),
        "{script}"
    );
    // 8 frames in chunks of 3, every wedge
    let export = &t["steps"][1];
    assert_eq!(
        export["parameterSpace"],
        serde_json::json!({
            "taskParameterDefinitions": [
                {"name": "Wedge", "type": "INT", "range": [0, 1]},
                {"name": "Frames", "type": "STRING", "range": ["1-3", "4-6", "7-8"]},
            ],
            "combination": "Wedge * Frames",
        })
    );
    assert_eq!(
        export["dependencies"],
        serde_json::json!([{"dependsOn": "Simulation"}])
    );
    assert_eq!(
        t["steps"][2]["dependencies"],
        serde_json::json!([{"dependsOn": "Simulation"}, {"dependsOn": "Export"}])
    );
    // every embedded script is valid bash
    for step in t["steps"].as_array().unwrap() {
        for f in step["script"]["embeddedFiles"]
            .as_array()
            .into_iter()
            .flatten()
        {
            let path = base.join(f["filename"].as_str().unwrap());
            std::fs::write(&path, f["data"].as_str().unwrap()).unwrap();
            let syntax = std::process::Command::new("/bin/bash")
                .arg("-n")
                .arg(&path)
                .output()
                .unwrap();
            assert!(
                syntax.status.success(),
                "{}: {}",
                path.display(),
                text(&syntax)
            );
        }
    }
    // the plan is the same plan as Slurm's, its jobs the template's steps
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(farm.join("farm.json")).unwrap()).unwrap();
    assert_eq!(plan["backend"], "openjd");
    let jobs: Vec<(&str, &str)> = plan["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| (j["name"].as_str().unwrap(), j["script"].as_str().unwrap()))
        .collect();
    assert_eq!(
        jobs,
        [
            ("sim", "template.json"),
            ("export", "template.json"),
            ("report", "template.json")
        ]
    );
    // nothing ran: status says so from the files, and resubmit points at the farm manager
    let o = nimbus()
        .args(["farm", "status", "--log-format", "json"])
        .arg(&farm)
        .env("PATH", path_without_sbatch(&base))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(s["wedges"][0]["state"], "not run", "{s}");
    assert_eq!(s["complete"], false);
    let o = nimbus()
        .args(["farm", "resubmit"])
        .arg(&farm)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("is not resubmitted by nimbus"),
        "{}",
        text(&o)
    );
    // --run-local without the openjd CLI: exit 3 with the remedy, the template still written
    let farm2 = base.join("farm2");
    let o = nimbus()
        .args(["farm", "submit", "--backend", "openjd", "--run-local"])
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&farm2)
        .env("PATH", path_without_sbatch(&base))
        .env("NIMBUS_OPENJD", base.join("no-openjd"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    assert!(
        text(&o).contains("no-openjd: no such file; install the Open Job Description CLI"),
        "{}",
        text(&o)
    );
    assert!(farm2.join("template.json").is_file());
}
