//! The Open Job Description backend (`farm submit --backend openjd`): the farm's plan written
//! as one OpenJD job template (specification `jobtemplate-2023-09`), the format AWS Deadline
//! Cloud runs. The plan is the same as Slurm's; each of its jobs becomes a step:
//!
//! - `Simulation`: a task per wedge (task parameter `Wedge`, INT): run the shot, or resume it
//!   from its checkpoint. Canceled (or timed out at `--time-limit`) it gets SIGTERM first
//!   (`NOTIFY_THEN_TERMINATE`, `--signal-margin` seconds of notice): nimbus finishes the frame,
//!   checkpoints and exits 130, and a retry of the task resumes it.
//! - `Export` (with `--export-chunk`): a task per (wedge, frame chunk), `Wedge * Frames`, each
//!   `nimbus export RUN --frames A-B`; after the whole Simulation step (OpenJD's dependencies
//!   are between steps).
//! - `Render` (with `--render`): a task per (wedge, frame), `Wedge * Frame`, Blender.
//! - `Report`: `nimbus farm report FARM_DIR` after every other step.
//!
//! The job parameter `FarmDir` (PATH, default `.`: the template's directory, which is the farm
//! directory) carries every path of the farm, so a farm manager's path mapping applies to it;
//! `NimbusBin` (STRING, default this binary: OpenJD allows only relative PATH defaults) is
//! where the workers have nimbus. `openjd run` (PyPI `openjd-cli`) runs the template here
//! (`--run-local`).
use super::plan::{FarmPlan, Job, JobKind};
use super::slurm::{export_array, sh, sim_sets};
use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

/// The template, relative to the farm directory: with it, the farm directory is a Deadline
/// Cloud job bundle.
pub const TEMPLATE: &str = "template.json";
/// The output of `--run-local`'s `openjd run`, relative to the farm directory.
pub const RUN_LOG: &str = "logs/openjd_run.log";
/// Longest notice OpenJD allows before it kills a canceled action (`notifyPeriodInSeconds`).
pub const MAX_NOTIFY_S: u32 = 600;

/// Where `--run-local` finds the `openjd` command first (see [`find_openjd`]).
pub const OPENJD_ENV: &str = "NIMBUS_OPENJD";

/// The OpenJD step of a plan job.
pub fn step_name(kind: JobKind) -> &'static str {
    match kind {
        JobKind::Simulation => "Simulation",
        JobKind::Export => "Export",
        JobKind::Render => "Render",
        JobKind::Report => "Report",
    }
}

/// The `openjd run` command line that runs the whole job here: the last step (Report) with
/// every step it depends on.
pub fn run_args(openjd: &Path, farm_dir: &Path) -> Vec<String> {
    vec![
        openjd.to_string_lossy().into_owned(),
        "run".into(),
        farm_dir.join(TEMPLATE).to_string_lossy().into_owned(),
        "--step".into(),
        step_name(JobKind::Report).into(),
        "--run-dependencies".into(),
    ]
}

/// Turns the plan's jobs into their OpenJD steps: the script is the template, the dependencies
/// are OpenJD step dependencies, and `submit` is the `openjd run` line of the step alone.
pub fn adapt_jobs(plan: &mut FarmPlan, farm_dir: &Path) {
    let template = farm_dir.join(TEMPLATE).to_string_lossy().into_owned();
    for job in &mut plan.jobs {
        job.script = TEMPLATE.into();
        for d in &mut job.depends_on {
            d.kind = "openjd_step".into();
        }
        if job.kind == JobKind::Export {
            // After the whole Simulation step: no waiting for frames.
            job.command = job.command.replace(
                "per (wedge, chunk): once RUN/manifest.json records frames A-B, ",
                "per (wedge, chunk), after the Simulation step: ",
            );
        }
        job.submit = vec![
            "openjd".into(),
            "run".into(),
            template.clone(),
            "--step".into(),
            step_name(job.kind).into(),
        ];
    }
}

fn wedge_range(plan: &FarmPlan, job: &Job) -> Value {
    // Every wedge by default; a list keeps whatever subset the job runs.
    let tasks: Vec<usize> = if job.tasks.is_empty() {
        plan.wedges.iter().map(|w| w.index).collect()
    } else {
        job.tasks.clone()
    };
    json!(tasks)
}

fn linux_only() -> Value {
    json!({
        "attributes": [{ "name": "attr.worker.os.family", "anyOf": ["linux"] }]
    })
}

/// `case "$WEDGE" in ...`: RUN and SETS of each wedge, relative to `$FARM`.
fn wedge_case(plan: &FarmPlan) -> String {
    let mut s = String::from("case \"$WEDGE\" in\n");
    for w in &plan.wedges {
        let sets: Vec<String> = sim_sets(plan, w)
            .iter()
            .map(|kv| format!("--set {}", sh(kv)))
            .collect();
        let rel = if w.run_dir.is_empty() {
            format!("runs/{}", w.name)
        } else {
            w.run_dir.clone()
        };
        s += &format!(
            "  {}) RUN=\"$FARM\"/{}; SETS=({}) ;;\n",
            w.index,
            sh(&rel),
            sets.join(" ")
        );
    }
    s += "  *) echo \"nimbus-farm: no wedge $WEDGE in this farm\" >&2; exit 2 ;;\nesac\n";
    s
}

/// A step's embedded bash script and the action that runs it with `args`.
fn script_step(name: &str, data: String, args: &[&str]) -> Value {
    let mut argv = vec![
        "{{Param.NimbusBin}}".to_string(),
        "{{Param.FarmDir}}".to_string(),
    ];
    argv.extend(args.iter().map(|a| a.to_string()));
    json!({
        "embeddedFiles": [{
            "name": name,
            "type": "TEXT",
            "runnable": true,
            "filename": format!("{}.sh", name.to_lowercase()),
            "data": data,
        }],
        "actions": { "onRun": {
            "command": format!("{{{{Task.File.{name}}}}}"),
            "args": argv,
        }},
    })
}

/// The Simulation step's script: `$1` nimbus, `$2` the farm directory, `$3` the wedge.
fn sim_script(plan: &FarmPlan) -> String {
    let mut s = String::from(
        "#!/usr/bin/env bash\n# Written by nimbus farm submit --backend openjd: a wedge's simulation task.\nset -u\nNIMBUS=$1; FARM=$(cd \"$2\" && pwd -P) || exit 3; WEDGE=$3\nCONFIG=$FARM/shot.yaml\nSTATE=$FARM/state\n",
    );
    s += &wedge_case(plan);
    s += SIM_BODY;
    s
}

/// Run, resume or nothing (a retry of a task whose run is complete); SIGTERM (OpenJD's notice
/// before it kills a canceled or timed-out action) is passed on to nimbus, which finishes the
/// frame, checkpoints and exits 130.
const SIM_BODY: &str = r#"mkdir -p "$STATE"
ATTEMPTS=$STATE/sim_$WEDGE.jsonl
if grep -q '"complete": true' "$RUN/manifest.json" 2>/dev/null; then
  echo "nimbus-farm: $RUN is complete; nothing to do"; exit 0
fi
if compgen -G "$RUN/checkpoints/*.nck" >/dev/null; then
  CMD=("$NIMBUS" resume "$RUN" --log-format json)
elif [ -e "$RUN/manifest.json" ]; then
  CMD=("$NIMBUS" run "$CONFIG" --out "$RUN" --force --log-format json "${SETS[@]}")
else
  CMD=("$NIMBUS" run "$CONFIG" --out "$RUN" --log-format json "${SETS[@]}")
fi
RESTART=$(wc -l <"$ATTEMPTS" 2>/dev/null || echo 0)
echo "nimbus-farm: wedge $WEDGE attempt $((RESTART + 1)) on $(hostname) at $(date -u +%FT%TZ): ${CMD[*]}"
"${CMD[@]}" &
PID=$!
trap 'kill -TERM $PID 2>/dev/null' TERM INT HUP
RC=0; wait $PID || RC=$?
while kill -0 $PID 2>/dev/null; do RC=0; wait $PID || RC=$?; done
trap - TERM INT HUP
printf '{"job":"openjd_%s","restart":%s,"exit":%s,"at":"%s"}\n' "$WEDGE" "$RESTART" "$RC" \
  "$(date -u +%FT%TZ)" >>"$ATTEMPTS"
case $RC in
  0) echo "nimbus-farm: wedge $WEDGE complete" ;;
  130) echo "nimbus-farm: wedge $WEDGE interrupted at a checkpoint (exit 130); a retry of this task resumes it" ;;
  *) echo "nimbus-farm: wedge $WEDGE failed (exit $RC)" >&2 ;;
esac
exit "$RC"
"#;

/// The Export step's script: `$3` the wedge, `$4` its frames `A-B`.
fn export_script(plan: &FarmPlan) -> Option<String> {
    let e = plan.export.as_ref()?;
    let mut s = String::from(
        "#!/usr/bin/env bash\n# Written by nimbus farm submit --backend openjd: a (wedge, frame chunk) export task.\nset -u\nNIMBUS=$1; FARM=$(cd \"$2\" && pwd -P) || exit 3; WEDGE=$3; FRAMES=$4\n",
    );
    s += &wedge_case(plan);
    s += &export_array(e);
    s += r#"CMD=("$NIMBUS" export "$RUN" --frames "$FRAMES" "${EXPORT[@]}")
echo "nimbus-farm: export wedge $WEDGE frames $FRAMES at $(date -u +%FT%TZ): ${CMD[*]}"
exec "${CMD[@]}"
"#;
    Some(s)
}

/// The Render step's script: `$3` the wedge, `$4` the frame; `$5` Blender, `$6` the script.
fn render_script(plan: &FarmPlan) -> Option<String> {
    let r = plan.render.as_ref()?;
    let mut s = String::from(
        "#!/usr/bin/env bash\n# Written by nimbus farm submit --backend openjd: a (wedge, frame) render task.\nset -u\nNIMBUS=$1; FARM=$(cd \"$2\" && pwd -P) || exit 3; WEDGE=$3; FRAME=$4; BLENDER=$5; SCRIPT=$6\n",
    );
    s += &wedge_case(plan);
    s += &format!(
        "PNG=$RUN/{render}/{}.$(printf '%0{}d' \"$FRAME\").png\nmkdir -p \"$RUN/{render}\"\n",
        plan.shot,
        r.frame_padding,
        render = crate::pipeline::run_dir::RunDir::RENDER
    );
    s += "RENDER=(\"$BLENDER\" -b --factory-startup --python-exit-code 1 -P \"$SCRIPT\" -- \"$RUN\" \"$PNG\" --frame \"$FRAME\" --min-coverage 0)\n";
    s += super::slurm::RENDER_BODY;
    Some(s)
}

/// The job template of a plan (JSON; `openjd check` validates it).
pub fn template(plan: &FarmPlan) -> Value {
    let mut params = vec![
        json!({
            "name": "FarmDir",
            "type": "PATH",
            "objectType": "DIRECTORY",
            "dataFlow": "INOUT",
            // OpenJD joins a relative default to the template's directory (and allows no `..`).
            "default": ".",
            "description": "The nimbus farm directory (farm.json, shot.yaml, runs/): on storage every worker reaches. Default: the directory of this template.",
        }),
        json!({
            // A STRING: OpenJD allows only relative PATH defaults, and the binary is where the
            // worker has it installed.
            "name": "NimbusBin",
            "type": "STRING",
            "default": plan.nimbus.to_string_lossy(),
            "description": "The nimbus binary the tasks run (on each worker).",
        }),
    ];
    if let Some(r) = &plan.render {
        params.push(json!({
            "name": "BlenderBin",
            "type": "STRING",
            "default": r.blender.to_string_lossy(),
            "description": "Blender, for the Render step.",
        }));
        params.push(json!({
            "name": "RenderScript",
            "type": "STRING",
            "default": r.script.to_string_lossy(),
            "description": "tools/render_blender.py of the nimbus checkout.",
        }));
    }
    let mut steps = Vec::new();
    let mut before_report = Vec::new();
    for job in &plan.jobs {
        let name = step_name(job.kind);
        let step = match job.kind {
            JobKind::Simulation => {
                let mut script = script_step(name, sim_script(plan), &["{{Task.Param.Wedge}}"]);
                let on_run = &mut script["actions"]["onRun"];
                on_run["cancelation"] = json!({
                    "mode": "NOTIFY_THEN_TERMINATE",
                    "notifyPeriodInSeconds": plan.slurm.signal_margin_s.clamp(1, MAX_NOTIFY_S),
                });
                if let Some(t) = plan
                    .slurm
                    .time_limit
                    .as_deref()
                    .and_then(|t| super::submit::time_limit_seconds(t).ok())
                {
                    // The notice comes out of the time limit: the action is canceled that long
                    // before it.
                    on_run["timeout"] =
                        json!(t.saturating_sub(plan.slurm.signal_margin_s as u64).max(1));
                }
                json!({
                    "name": name,
                    "description": "One task per wedge: run the shot, or resume it from its checkpoint. Exit 130: stopped at a checkpoint (canceled or timed out); a retry resumes it.",
                    "parameterSpace": { "taskParameterDefinitions": [
                        { "name": "Wedge", "type": "INT", "range": wedge_range(plan, job) }
                    ]},
                    "script": script,
                    "hostRequirements": linux_only(),
                })
            }
            JobKind::Export => {
                let Some(e) = &plan.export else { continue };
                let chunks: Vec<String> = (0..e.chunks(plan.frame_start, plan.frame_end))
                    .map(|c| {
                        let (a, b) = e.frames(plan.frame_start, plan.frame_end, c);
                        format!("{a}-{b}")
                    })
                    .collect();
                json!({
                    "name": name,
                    "description": "One task per (wedge, frame chunk): nimbus export RUN --frames A-B into RUN/exports/NAME/.",
                    "parameterSpace": {
                        "taskParameterDefinitions": [
                            { "name": "Wedge", "type": "INT", "range": wedge_range(plan, job) },
                            { "name": "Frames", "type": "STRING", "range": chunks },
                        ],
                        "combination": "Wedge * Frames",
                    },
                    "script": script_step(name, export_script(plan).unwrap_or_default(),
                        &["{{Task.Param.Wedge}}", "{{Task.Param.Frames}}"]),
                    "hostRequirements": linux_only(),
                    "dependencies": [{ "dependsOn": "Simulation" }],
                })
            }
            JobKind::Render => json!({
                "name": name,
                "description": "One task per (wedge, frame): Blender renders RUN/render/<shot>.<frame>.png.",
                "parameterSpace": {
                    "taskParameterDefinitions": [
                        { "name": "Wedge", "type": "INT", "range": wedge_range(plan, job) },
                        { "name": "Frame", "type": "INT",
                          "range": format!("{}-{}", plan.frame_start, plan.frame_end) },
                    ],
                    "combination": "Wedge * Frame",
                },
                "script": script_step(name, render_script(plan).unwrap_or_default(),
                    &["{{Task.Param.Wedge}}", "{{Task.Param.Frame}}",
                      "{{Param.BlenderBin}}", "{{Param.RenderScript}}"]),
                "hostRequirements": linux_only(),
                "dependencies": [{ "dependsOn": "Simulation" }],
            }),
            JobKind::Report => json!({
                "name": name,
                "description": "Check every frame against the manifests; write farm_report.json and the wedge contact sheet.",
                "script": { "actions": { "onRun": {
                    "command": "{{Param.NimbusBin}}",
                    "args": ["farm", "report", "{{Param.FarmDir}}"],
                }}},
                "hostRequirements": linux_only(),
                "dependencies": before_report
                    .iter()
                    .map(|s: &&str| json!({ "dependsOn": s }))
                    .collect::<Vec<_>>(),
            }),
        };
        if job.kind != JobKind::Report {
            before_report.push(name);
        }
        steps.push(step);
    }
    json!({
        "specificationVersion": "jobtemplate-2023-09",
        "name": format!("nimbus farm: {} ({} wedge(s))", plan.shot, plan.wedges.len()),
        "description": format!(
            "Written by nimbus {} farm submit --backend openjd from {}. The plan is farm.json in the farm directory.",
            plan.version,
            plan.source_config.display()
        ),
        "parameterDefinitions": params,
        "steps": steps,
    })
}

/// Writes the template into the farm directory; returns its path.
pub fn write(plan: &FarmPlan, farm_dir: &Path) -> Result<PathBuf> {
    let path = farm_dir.join(TEMPLATE);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let mut text =
        serde_json::to_string_pretty(&template(plan)).map_err(|e| Error::Runtime(e.to_string()))?;
    text.push('\n');
    write_atomic(&path, text.as_bytes())?;
    Ok(path)
}

/// Where `tools/setup.sh --farm` installs the openjd CLI (a venv; `NIMBUS_OPENJD_VENV` there).
pub const DEFAULT_VENV: &str = "/opt/nimbus/openjd";

/// The `openjd` command: `NIMBUS_OPENJD`, else `openjd` on PATH, else the one tools/setup.sh
/// --farm installs (`/opt/nimbus/openjd/bin/openjd`); missing is exit 3 with the remedy.
pub fn find_openjd() -> Result<PathBuf> {
    if let Some(p) = std::env::var_os(OPENJD_ENV) {
        let p = PathBuf::from(p);
        if p.is_file() {
            return Ok(p);
        }
        return Err(Error::Runtime(format!(
            "{OPENJD_ENV}={}: no such file; {REMEDY}",
            p.display()
        )));
    }
    std::env::var_os("PATH")
        .and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|d| d.join("openjd"))
                .find(|p| p.is_file())
        })
        .or_else(|| Some(Path::new(DEFAULT_VENV).join("bin/openjd")).filter(|p| p.is_file()))
        .ok_or_else(|| Error::Runtime(format!("openjd not found on PATH: {REMEDY}")))
}

const REMEDY: &str = "install the Open Job Description CLI (tools/setup.sh --farm puts it in \
     /opt/nimbus/openjd; or `pip install openjd-cli`) and put `openjd` on PATH or set \
     NIMBUS_OPENJD to it";

/// What `--run-local` did.
pub struct LocalRun {
    pub command: Vec<String>,
    pub seconds: f64,
    pub log: PathBuf,
}

/// Runs the whole template here with `openjd run` (every step, in dependency order, in one
/// session), its output to `logs/openjd_run.log`. A failed task is exit 3 with the log's tail.
pub fn run_local(farm_dir: &Path) -> Result<LocalRun> {
    let openjd = find_openjd()?;
    let command = run_args(&openjd, farm_dir);
    let log = farm_dir.join(RUN_LOG);
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log)
        .map_err(|e| Error::io(&log, e))?;
    let err = file.try_clone().map_err(|e| Error::io(&log, e))?;
    let t = Instant::now();
    let status = Command::new(&command[0])
        .args(&command[1..])
        .current_dir(farm_dir)
        .stdin(Stdio::null())
        .stdout(file)
        .stderr(err)
        .status()
        .map_err(|e| Error::Runtime(format!("cannot run {}: {e}: {REMEDY}", command[0])))?;
    let seconds = t.elapsed().as_secs_f64();
    let record = json!({
        "command": command,
        "exit": status.code(),
        "seconds": seconds,
        "at_unix_s": std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
    });
    let state = farm_dir.join("state/openjd_run.jsonl");
    let mut line = record.to_string();
    line.push('\n');
    use std::io::Write;
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&state)
        .and_then(|mut f| f.write_all(line.as_bytes()))
        .map_err(|e| Error::io(&state, e))?;
    if !status.success() {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        let tail: Vec<&str> = text.lines().rev().take(15).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        return Err(Error::Runtime(format!(
            "openjd run failed ({status}) after {seconds:.1} s; the last lines of {}:\n{}\n\
             (a task stopped at a checkpoint resumes when run again: {})",
            log.display(),
            tail.join("\n"),
            command.iter().map(|a| sh(a)).collect::<Vec<_>>().join(" ")
        )));
    }
    Ok(LocalRun {
        command,
        seconds,
        log,
    })
}
