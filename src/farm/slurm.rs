//! The Slurm backend: the batch scripts of a plan, `sbatch` submission and the queue's view of
//! the jobs (`squeue`). Only the Slurm client commands are used, so it runs wherever a login
//! node can submit.
use super::plan::{run_dir, FarmPlan, Job, JobKind};
use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// The remedy printed with every failure to reach Slurm.
const REMEDY: &str = "install the Slurm client (tools/setup.sh --farm), point SLURM_CONF at the \
     cluster's slurm.conf and check that `sinfo` answers; for a one-node cluster on this machine \
     see tools/slurm-local.sh";

/// Quotes a word for bash (only when it needs it).
pub fn sh(word: &str) -> String {
    if !word.is_empty()
        && word
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+:=,@%".contains(c))
    {
        word.to_string()
    } else {
        format!("'{}'", word.replace('\'', "'\\''"))
    }
}

fn sh_path(p: &Path) -> String {
    sh(&p.to_string_lossy())
}

/// The `#SBATCH` lines every job of the farm shares.
fn common_header(plan: &FarmPlan, job: &Job, farm_dir: &Path, log: &str) -> String {
    let mut s = String::from("#!/bin/bash\n");
    s += &format!(
        "# Written by nimbus farm submit: job '{}' of {}.\n",
        job.name,
        farm_dir.display()
    );
    s += &format!("#SBATCH --job-name=nimbus-{}-{}\n", plan.shot, job.name);
    s += &format!(
        "#SBATCH --output={}\n",
        farm_dir.join("logs").join(log).display()
    );
    s += "#SBATCH --open-mode=append\n";
    if let Some(p) = &plan.slurm.partition {
        s += &format!("#SBATCH --partition={p}\n");
    }
    if let Some(t) = &plan.slurm.time_limit {
        s += &format!("#SBATCH --time={t}\n");
    }
    s
}

/// The `case` that sets RUN (and SETS) for the array task's wedge.
fn wedge_case(plan: &FarmPlan, farm_dir: &Path) -> String {
    let mut s = String::from("case \"$SLURM_ARRAY_TASK_ID\" in\n");
    for w in &plan.wedges {
        let sets: Vec<String> = sim_sets(plan, w)
            .iter()
            .map(|kv| format!("--set {}", sh(kv)))
            .collect();
        s += &format!(
            "  {}) RUN={}; SETS=({}) ;;\n",
            w.index,
            sh_path(&run_dir(farm_dir, w)),
            sets.join(" ")
        );
    }
    s += "  *) echo \"nimbus-farm: no wedge $SLURM_ARRAY_TASK_ID in this farm\" >&2; exit 2 ;;\nesac\n";
    s
}

/// The `--set`s of a wedge's simulation: its wedge values, and `export.particles=true` when the
/// farm has an export stage (`nimbus export` splats the particle caches).
pub fn sim_sets(plan: &FarmPlan, w: &super::wedge::Wedge) -> Vec<String> {
    let mut sets = w.sets();
    if plan.export.is_some() {
        sets.push("export.particles=true".into());
    }
    sets
}

/// The simulation array: run or resume the wedge's shot; SIGTERM before the time limit reaches
/// nimbus, which finishes the frame, checkpoints and exits 130, and the task requeues itself.
pub fn simulation_script(plan: &FarmPlan, job: &Job, farm_dir: &Path) -> String {
    let mut s = common_header(plan, job, farm_dir, "sim_%a.log");
    s += "#SBATCH --requeue\n";
    s += &format!("#SBATCH --signal=B:TERM@{}\n", plan.slurm.signal_margin_s);
    s += "set -u\n";
    s += &format!("NIMBUS={}\n", sh_path(&plan.nimbus));
    s += &format!("CONFIG={}\n", sh_path(&plan.config));
    s += &format!("STATE={}\n", sh_path(&farm_dir.join("state")));
    s += &format!("CRASH_REQUEUES={}\n", plan.slurm.crash_requeues);
    s += &wedge_case(plan, farm_dir);
    s += SIM_BODY;
    s
}

/// Shared by every simulation task (bash). Kept as one block so the logic reads top to bottom.
const SIM_BODY: &str = r#"ME=${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}
ATTEMPTS=$STATE/sim_${SLURM_ARRAY_TASK_ID}.jsonl
mkdir -p "$STATE"
# A run with a checkpoint resumes; one that died before its first checkpoint starts over
# (--force removes only nimbus's own files); otherwise a fresh run.
if compgen -G "$RUN/checkpoints/*.nck" >/dev/null; then
  CMD=("$NIMBUS" resume "$RUN" --log-format json)
elif [ -e "$RUN/manifest.json" ]; then
  CMD=("$NIMBUS" run "$CONFIG" --out "$RUN" --force --log-format json "${SETS[@]}")
else
  CMD=("$NIMBUS" run "$CONFIG" --out "$RUN" --log-format json "${SETS[@]}")
fi
echo "nimbus-farm: job $ME restart ${SLURM_RESTART_COUNT:-0} on $(hostname) at $(date -u +%FT%TZ): ${CMD[*]}"
# Slurm signals only this shell (--signal=B:...): pass the TERM on to nimbus, then wait for it
# to finish its frame and checkpoint.
"${CMD[@]}" &
PID=$!
trap 'kill -TERM $PID 2>/dev/null' TERM INT HUP
RC=0; wait $PID || RC=$?
while kill -0 $PID 2>/dev/null; do RC=0; wait $PID || RC=$?; done
trap - TERM INT HUP
printf '{"job":"%s","restart":%s,"exit":%s,"at":"%s"}\n' "$ME" "${SLURM_RESTART_COUNT:-0}" "$RC" \
  "$(date -u +%FT%TZ)" >>"$ATTEMPTS"
requeue() {
  # Only a task still RUNNING is requeued: one its user cancelled (scancel) is already
  # COMPLETING when its shell gets here; the time-limit signal leaves it RUNNING.
  if ! scontrol show job "$ME" -o 2>/dev/null | grep -q 'JobState=RUNNING'; then
    echo "nimbus-farm: $ME was cancelled; not requeued"; exit "$RC"
  fi
  echo "nimbus-farm: $ME $1; requeued (resumes from its checkpoint)"
  scontrol requeue "$ME" || { echo "nimbus-farm: scontrol requeue $ME failed" >&2; exit 3; }
  exit "$RC"
}
case $RC in
  0) echo "nimbus-farm: $ME complete" ;;
  130) requeue "interrupted (exit 130)" ;;
  137 | 139 | 134 | 143)
    CRASHES=$(grep -c '"exit":\(137\|139\|134\|143\)' "$ATTEMPTS" || true)
    if [ "$CRASHES" -le "$CRASH_REQUEUES" ]; then requeue "killed (exit $RC, crash $CRASHES of $CRASH_REQUEUES allowed)"; fi
    echo "nimbus-farm: $ME killed (exit $RC) $CRASHES times; giving up" >&2 ;;
  *) echo "nimbus-farm: $ME failed (exit $RC)" >&2 ;;
esac
exit "$RC"
"#;

/// The report: one job after every simulation (and render) task, whatever their outcome.
pub fn report_script(plan: &FarmPlan, job: &Job, farm_dir: &Path) -> String {
    let mut s = common_header(plan, job, farm_dir, &format!("{}.log", job.name));
    s += "set -u\n";
    s += &format!(
        "exec {} farm report {}\n",
        sh_path(&plan.nimbus),
        sh_path(farm_dir)
    );
    s
}

/// The render array: one task per (wedge, frame), Blender through tools/render_blender.py.
pub fn render_script(plan: &FarmPlan, job: &Job, farm_dir: &Path) -> Option<String> {
    let r = plan.render.as_ref()?;
    let frames = plan.frame_end - plan.frame_start + 1;
    let mut s = common_header(plan, job, farm_dir, "render_%a.log");
    s += "set -u\n";
    s += &format!("FRAMES={frames}\nSTART={}\n", plan.frame_start);
    s += "WEDGE=$((SLURM_ARRAY_TASK_ID / FRAMES))\nFRAME=$((START + SLURM_ARRAY_TASK_ID % FRAMES))\n";
    s += &wedge_case(plan, farm_dir).replace("\"$SLURM_ARRAY_TASK_ID\"", "\"$WEDGE\"");
    s += &format!(
        "PNG=$RUN/{render}/{}.$(printf '%0{}d' $FRAME).png\nmkdir -p \"$RUN/{render}\"\n",
        plan.shot,
        r.frame_padding,
        render = crate::pipeline::run_dir::RunDir::RENDER
    );
    s += &format!(
        "RENDER=({} -b --factory-startup --python-exit-code 1 -P {} -- \"$RUN\" \"$PNG\" --frame $FRAME --min-coverage 0)\n",
        sh_path(&r.blender),
        sh_path(&r.script)
    );
    s += RENDER_BODY;
    Some(s)
}

/// Renders the frame. The script renders with the density grid's physical extinction, so a
/// frame before the cloud forms (an empty density grid) is the sky alone, not an error.
pub(crate) const RENDER_BODY: &str = r#"echo "nimbus-farm: render $RUN frame $FRAME -> $PNG"
"${RENDER[@]}"
"#;

/// The export array: one task per (wedge, chunk), numbered `wedge * chunks + chunk`. It waits
/// until the wedge's manifest records every frame of its chunk (so chunks start while the
/// simulation goes on), then runs `nimbus export RUN --frames A-B` into `exports/<name>/`, which
/// needs no run lock. While the simulation task is back in the queue (requeued) the export task
/// requeues itself, so a waiting export never holds the node the simulation needs; when the
/// simulation task has left the queue without the frames it gives up (exit 3).
pub fn export_script(plan: &FarmPlan, job: &Job, farm_dir: &Path) -> Option<String> {
    let e = plan.export.as_ref()?;
    let chunks = e.chunks(plan.frame_start, plan.frame_end);
    let mut s = common_header(plan, job, farm_dir, "export_%a.log");
    s += "#SBATCH --requeue\n";
    s += "set -u\n";
    s += &format!("NIMBUS={}\n", sh_path(&plan.nimbus));
    s += &format!(
        "START={}\nEND={}\nCHUNK={}\nCHUNKS={chunks}\nPOLL=2\n",
        plan.frame_start, plan.frame_end, e.chunk
    );
    s += "WEDGE=$((SLURM_ARRAY_TASK_ID / CHUNKS))\nC=$((SLURM_ARRAY_TASK_ID % CHUNKS))\n";
    s += "A=$((START + C * CHUNK))\nB=$((A + CHUNK - 1))\nif [ $B -gt $END ]; then B=$END; fi\n";
    s += &wedge_case(plan, farm_dir).replace("\"$SLURM_ARRAY_TASK_ID\"", "\"$WEDGE\"");
    s += &export_array(e);
    s += EXPORT_BODY;
    Some(s)
}

/// The bash array `EXPORT=(...)` of an export task's `nimbus export` flags (every backend).
pub fn export_array(e: &super::plan::ExportSettings) -> String {
    let mut args: Vec<String> = e
        .sets
        .iter()
        .map(|kv| format!("--set {}", sh(kv)))
        .collect();
    if let Some(n) = &e.name {
        args.push(format!("--name {}", sh(n)));
    }
    format!("EXPORT=({})\n", args.join(" "))
}

/// Shared by every export task (bash).
const EXPORT_BODY: &str = r#"ME=${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}
SIM=${NIMBUS_FARM_SIM_JOB:?the job id of the simulation array (sbatch --export=ALL,NIMBUS_FARM_SIM_JOB=ID)}_$WEDGE
echo "nimbus-farm: export $ME restart ${SLURM_RESTART_COUNT:-0}: frames $A-$B of $RUN (simulation task $SIM) on $(hostname) at $(date -u +%FT%TZ)"
# The manifest is rewritten whole and atomically after each frame: a frame it records is on disk.
have_frames() {
  local got f
  got=$(grep -o '"frame": [0-9]*,' "$RUN/manifest.json" 2>/dev/null) || return 1
  for ((f = A; f <= B; f++)); do grep -qx "\"frame\": $f," <<<"$got" || return 1; done
}
sim_state() {
  local out
  if out=$(squeue -h -t all -j "$SIM" -o %T 2>&1); then
    out=$(head -n 1 <<<"$out")
    echo "${out:-GONE}"
  elif grep -qi "invalid job id" <<<"$out"; then
    echo GONE
  else
    echo UNREACHABLE
  fi
}
while ! have_frames; do
  ST=$(sim_state)
  case $ST in
    RUNNING | CONFIGURING | COMPLETING | SIGNALING | STAGE_OUT | RESIZING | UNREACHABLE)
      sleep $POLL ;;
    PENDING | REQUEUED | REQUEUE_HOLD | REQUEUE_FED | SUSPENDED | STOPPED | SPECIAL_EXIT | RESV_DEL_HOLD)
      # The simulation waits in the queue: give the node back rather than hold it waiting.
      if scontrol show job "$ME" -o 2>/dev/null | grep -q 'JobState=RUNNING'; then
        echo "nimbus-farm: export $ME: simulation $SIM is $ST; requeued to wait for frames $A-$B in the queue"
        scontrol requeue "$ME" && exit 0
        echo "nimbus-farm: scontrol requeue $ME failed; waiting here" >&2
      fi
      sleep $POLL ;;
    *)
      have_frames && break
      echo "nimbus-farm: export $ME: simulation task $SIM left the queue ($ST) without frames $A-$B in $RUN/manifest.json; giving up (see logs/sim_$WEDGE.log; nimbus farm resubmit exports them again)" >&2
      exit 3 ;;
  esac
done
CMD=("$NIMBUS" export "$RUN" --frames "$A-$B" "${EXPORT[@]}")
RC=0
for TRY in 1 2 3; do
  echo "nimbus-farm: export $ME try $TRY at $(date -u +%FT%TZ): ${CMD[*]}"
  RC=0; "${CMD[@]}" || RC=$?
  if [ $RC -eq 0 ]; then echo "nimbus-farm: export $ME done at $(date -u +%FT%TZ)"; exit 0; fi
  echo "nimbus-farm: export $ME: exit $RC" >&2
  sleep $POLL
done
exit $RC
"#;

/// The script text of a job.
pub fn script_for(plan: &FarmPlan, job: &Job, farm_dir: &Path) -> String {
    match job.kind {
        JobKind::Simulation => simulation_script(plan, job, farm_dir),
        JobKind::Report => report_script(plan, job, farm_dir),
        JobKind::Render => render_script(plan, job, farm_dir).unwrap_or_default(),
        JobKind::Export => export_script(plan, job, farm_dir).unwrap_or_default(),
    }
}

/// The sbatch command line of a job, with the ids of the jobs it depends on.
pub fn submit_args(job: &Job, plan: &FarmPlan, farm_dir: &Path, frames: u32) -> Vec<String> {
    let mut args = vec!["sbatch".to_string(), "--parsable".to_string()];
    match job.kind {
        JobKind::Simulation => args.push(format!("--array={}", array_spec(&job.tasks))),
        JobKind::Render => {
            let tasks: Vec<usize> = job
                .tasks
                .iter()
                .flat_map(|&w| (0..frames as usize).map(move |f| w * frames as usize + f))
                .collect();
            args.push(format!("--array={}", array_spec(&tasks)));
        }
        JobKind::Export => {
            let chunks = plan
                .export
                .as_ref()
                .map_or(1, |e| e.chunks(plan.frame_start, plan.frame_end))
                as usize;
            let tasks: Vec<usize> = job
                .tasks
                .iter()
                .flat_map(|&w| (0..chunks).map(move |c| w * chunks + c))
                .collect();
            args.push(format!("--array={}", array_spec(&tasks)));
            // The script asks the queue about its wedge's simulation task.
            if let Some(sim) = job
                .depends_on
                .iter()
                .find_map(|d| plan.job(&d.job).filter(|j| j.kind == JobKind::Simulation))
            {
                args.push(format!(
                    "--export=ALL,NIMBUS_FARM_SIM_JOB={}",
                    sim.slurm_id.as_deref().unwrap_or("<id>")
                ));
            }
        }
        JobKind::Report => {}
    }
    let deps: Vec<String> = job
        .depends_on
        .iter()
        .filter_map(|d| {
            let id = plan.job(&d.job)?.slurm_id.as_deref().unwrap_or("<id>");
            Some(format!("{}:{id}", d.kind))
        })
        .collect();
    if !deps.is_empty() {
        args.push(format!("--dependency={}", deps.join(",")));
    }
    args.push(farm_dir.join(&job.script).to_string_lossy().into_owned());
    args
}

/// `0-3,5,7-8` from sorted indices.
pub fn array_spec(tasks: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut i = 0;
    while i < tasks.len() {
        let mut j = i;
        while j + 1 < tasks.len() && tasks[j + 1] == tasks[j] + 1 {
            j += 1;
        }
        parts.push(if i == j {
            tasks[i].to_string()
        } else {
            format!("{}-{}", tasks[i], tasks[j])
        });
        i = j + 1;
    }
    parts.join(",")
}

/// Runs `sbatch --parsable ...` and returns the job id; a missing sbatch or an unreachable
/// controller is a runtime error (exit 3) with the remedy.
pub fn sbatch(args: &[String]) -> Result<String> {
    let out = Command::new(&args[0])
        .args(&args[1..])
        .output()
        .map_err(|e| {
            Error::Runtime(if e.kind() == std::io::ErrorKind::NotFound {
                format!("sbatch not found on PATH: {REMEDY}")
            } else {
                format!("cannot run sbatch: {e}: {REMEDY}")
            })
        })?;
    if !out.status.success() {
        let why = String::from_utf8_lossy(&out.stderr);
        let why = why
            .lines()
            .rfind(|l| !l.trim().is_empty())
            .unwrap_or("")
            .trim();
        return Err(Error::Runtime(format!(
            "sbatch failed ({}): {why}: {REMEDY}",
            out.status
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    // `--parsable` prints `id` or `id;cluster`.
    let id = text.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        return Err(Error::Runtime(format!(
            "sbatch printed no job id (got {:?})",
            text.trim()
        )));
    }
    Ok(id)
}

/// What the queue says about one job or array task.
#[derive(Debug, Clone, PartialEq)]
pub struct QueueEntry {
    /// PENDING, RUNNING, REQUEUED, COMPLETING, ...
    pub state: String,
    /// Why it is pending (BeginTime, Dependency, Resources, ...) or None.
    pub reason: String,
    pub restarts: u32,
}

/// The queue's entries for the given job ids, keyed by `id` (single job) or `id_task` (array
/// task). Jobs that have left the queue are absent. Err when squeue cannot be run or the
/// controller does not answer.
pub fn queue(ids: &[&str]) -> Result<BTreeMap<String, QueueEntry>> {
    let mut map = BTreeMap::new();
    if ids.is_empty() {
        return Ok(map);
    }
    let out = Command::new("squeue")
        .args(["-h", "-r", "--states=all", "-o", "%i|%T|%r|%A"])
        .arg(format!("--jobs={}", ids.join(",")))
        .output()
        .map_err(|e| Error::Runtime(format!("cannot run squeue: {e}: {REMEDY}")))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        // squeue fails on ids the controller has forgotten: that is "not in the queue".
        if err.contains("Invalid job id") {
            return Ok(map);
        }
        return Err(Error::Runtime(format!(
            "squeue failed: {}: {REMEDY}",
            err.trim()
        )));
    }
    for line in text.lines() {
        let f: Vec<&str> = line.split('|').collect();
        if f.len() < 4 {
            continue;
        }
        let restarts = restart_count(f[3]);
        map.insert(
            f[0].to_string(),
            QueueEntry {
                state: f[1].to_string(),
                reason: f[2].to_string(),
                restarts,
            },
        );
    }
    Ok(map)
}

/// `Restarts=N` of a job from `scontrol show job` (0 when unknown).
fn restart_count(job_id: &str) -> u32 {
    let Ok(out) = Command::new("scontrol")
        .args(["show", "job", "-o", job_id])
        .output()
    else {
        return 0;
    };
    String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .find_map(|w| w.strip_prefix("Restarts="))
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn array_specs_are_ranges() {
        assert_eq!(array_spec(&[0, 1, 2, 3]), "0-3");
        assert_eq!(array_spec(&[0, 2, 3, 5]), "0,2-3,5");
        assert_eq!(array_spec(&[4]), "4");
    }

    #[test]
    fn shell_words_are_quoted() {
        assert_eq!(sh("a/b.c"), "a/b.c");
        assert_eq!(sh("a b"), "'a b'");
        assert_eq!(sh("it's"), "'it'\\''s'");
        assert_eq!(sh("[1,1,0]"), "'[1,1,0]'");
    }
}
