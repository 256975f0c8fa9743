"""The biasgt workflow on a throwaway single-node SLURM cluster, checked against a local run.

    python tests/cluster/slurm_local.py [--keep]         (as root; '.ci/run' calls it)

What it does, in a fresh temporary folder:

1. Installs Debian's ``slurmctld``, ``slurmd``, ``slurm-client`` and ``munge`` when missing
   (apt-get, as root).
2. Simulates a recording with ``biasgt simulate`` and cuts its IMU file to the header (a
   recording that lost its samples).
3. Starts the reference, a local run of a small workflow config, in the background at the lowest
   CPU priority (it takes the cores while the SLURM run below waits for status checks): three
   10-s simulated sequences (train, val, test) through every stage, and the learning stage at a
   tiny preset (one method, one seed, 10 steps) up to Table I and the training report.
4. Starts a one-node cluster: ``munged`` (as the munge user) with its own socket, then
   ``slurmctld`` and ``slurmd`` with a config written to ``/etc/slurm/slurm.conf`` (no cgroups, no
   accounting database; state, spool, pid and log files in the temporary folder); waits until
   the node is idle.
5. Runs the same config plus the broken recording as a fourth sequence with ``biasgt run
   --profile slurm`` (the repository's profile, whose groups make one SLURM job of each
   sequence's six stages and one of train + evaluate) and ``--slurm-status-command squeue``.
   Checks that every job ran in a SLURM job (Snakemake's log names the SLURM job id of the job,
   or of the group job holding it; the job's own log ``logs/<stage>/<name>.log`` says it ran under
   that id; SLURM's job-completion log lists it COMPLETED); that the broken sequence's job FAILED
   in SLURM twice at ingest (the profile's ``retries: 1``), ``biasgt run`` exited 2 naming the
   rule and its log and nothing of that sequence was left half-written.
6. Waits for the local run and compares the outputs file by file (every file under ``results/``;
   the fields allowed to differ are listed in ``ALLOWED_DIFFERENCES``; trained runs and
   evaluation folders hold wall-clock times, so of those the evaluation table must match: Table I).
7. Repairs the IMU file and reruns: only that sequence's 5 jobs run, every finished file is
   untouched.
8. Stops the daemons by their pid files (also on failure), removes the config and the
   temporary folder (kept with --keep or on failure).

Exits 0 when every check holds, 1 otherwise; prints the timings and the checks. Takes 2.5-3
minutes on 2 cores: measured 141 s on idle cores (SLURM run 111 s, 23 + 10 jobs in 7 + 2 SLURM
jobs; rerun 22 s, 5 jobs in one SLURM job; the local run, 58 s at the lowest priority, ended
inside the SLURM run), 181 s with another process busy on one core. Most of a SLURM job's time is
Snakemake's start-up in it (once for the job, once per rule's srun step) and the plugin's
status-check interval (it noticed finished jobs 3-12 s after their end).
"""

from __future__ import annotations

import argparse
import contextlib
import getpass
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = {"slurmctld": "slurmctld", "slurmd": "slurmd", "sbatch": "slurm-client", "munged": "munge"}
RUN_TIMEOUT_S = 900  # one 'biasgt run' (about 140 s on idle cores; a hang guard, generous for busy machines).
# Snakemake ignores SIGTERM while jobs run: timeout -k
INIT_SECONDS = 3  # --slurm-init-seconds-before-status-checks; MinJobAge below is 3x or more
MIN_JOB_AGE_S = 300
SLURM_CONF = Path("/etc/slurm/slurm.conf")
CONF_MARKER = "# throwaway single-node cluster of biasgt's tests/cluster/slurm_local.py: removed when it stops"

CONFIG = """\
sequences:
  - {name: sim_a, source: simulate, split: train, preset: handheld, duration_s: 10, seed: 1, pose_format: mocap}
  - {name: sim_b, source: simulate, split: test, preset: aggressive_drone, duration_s: 10, seed: 2, pose_format: mocap}
  - {name: sim_c, source: simulate, split: val, preset: handheld, duration_s: 10, seed: 3, pose_format: mocap}
"""
#: The learning stage at a tiny, deterministic setting (one thread, one method).
LEARNING = """\
windows: {accept_warn: true}
training:
  methods: [regression_rnn]
  preset: tiny
  options: {max_steps: 10, batch_size: 8, val_every: 5, checkpoint_every: 5, warmup_steps: 2, threads: 1,
            device: cpu}
evaluation: {samples: 2, samplers: [ddim], references: []}
"""
#: A recorded sequence whose IMU file holds no samples: its ingest job fails.
BROKEN = """\
  - {name: broken, source: asl, split: none, path: broken}
"""
BROKEN_RULES = ("ingest", "recover", "interpolate", "validate", "report")
#: Jobs (rule instances) of the good sequences: 3 x (simulate, ingest, recover, interpolate, validate,
#: report), windows, and the learning stage's train, evaluate, table, training_report (no reference
#: row: each would be one more SLURM job of ~10 s; their evaluation is tested in the suite).
GOOD_JOBS = 3 * 6 + 1 + 4
#: ... in SLURM jobs: the profile groups a sequence's 6 stages into one job, and train with evaluate:
#: 3 sequences, windows, train+evaluate, table, training_report.
GOOD_SLURM_JOBS = 3 + 1 + 3

#: Files whose content may legitimately differ between two runs, and what may differ in them.
ALLOWED_DIFFERENCES = {
    "recovery.json": "runtime_s and timings_s (wall-clock times of the solve)",
    "report.html": "its generation time and the 'recovery runtime' row",
}


class CheckFailed(Exception):
    """A check of this script failed."""


def check(ok: bool, what: str) -> None:
    print(("  ok    " if ok else "  FAIL  ") + what, flush=True)
    if not ok:
        raise CheckFailed(what)


# --------------------------------------------------------------------------------------------
# The cluster
# --------------------------------------------------------------------------------------------


def ensure_packages() -> None:
    """Install the Debian SLURM and munge packages when a daemon or client is missing."""
    missing = sorted({pkg for exe, pkg in PACKAGES.items() if not shutil.which(exe)})
    if not missing:
        return
    if os.geteuid() != 0:
        raise CheckFailed(f"missing {', '.join(missing)}: run as root, or apt-get install {' '.join(missing)}")
    print(f"installing {' '.join(missing)} (apt-get)", flush=True)
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    subprocess.run(["apt-get", "update", "-qq"], check=True, env=env)
    subprocess.run(["apt-get", "install", "-y", "-qq", *missing], check=True, env=env, stdout=subprocess.DEVNULL)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


def _real_memory_mb() -> int:
    total_kb = int(re.search(r"MemTotal:\s+(\d+)", Path("/proc/meminfo").read_text()).group(1))
    return int(total_kb / 1024 * 0.8)


@dataclass(frozen=True)
class Cluster:
    """A running one-node cluster: its folder and config file."""

    root: Path
    conf: Path

    @property
    def jobcomp(self) -> Path:
        """SLURM's job-completion log (jobcomp/filetxt): one line per finished job."""
        return self.root / "jobcomp.txt"

    def finished_jobs(self) -> dict[str, str]:
        """SLURM job id -> final state, from the job-completion log."""
        states = {}
        if self.jobcomp.exists():
            for line in self.jobcomp.read_text().splitlines():
                fields = dict(kv.split("=", 1) for kv in line.split() if "=" in kv)
                states[fields["JobId"]] = fields["JobState"]
        return states


def write_slurm_conf(root: Path) -> Path:
    """Write the cluster's config where every SLURM command finds it, ``/etc/slurm/slurm.conf``.

    (Not a ``SLURM_CONF`` elsewhere: the plugin's job step removes every ``SLURM_*`` variable but
    the job's identity before it calls ``srun`` inside the job.) Refuses to replace a config this
    script did not write.
    """
    host = socket.gethostname()
    cpus = os.cpu_count() or 1
    user = getpass.getuser()
    if SLURM_CONF.exists() and not SLURM_CONF.read_text().startswith(CONF_MARKER):
        raise CheckFailed(f"{SLURM_CONF} exists (a real SLURM setup?): run this on a machine without one")
    SLURM_CONF.parent.mkdir(parents=True, exist_ok=True)
    conf = SLURM_CONF
    conf.write_text(f"""\
{CONF_MARKER}
ClusterName=biasgt-ci
SlurmctldHost={host}
SlurmctldPort={_free_port()}
SlurmdPort={_free_port()}
SlurmUser={user}
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket={root / 'munge' / 'munge.socket'}
StateSaveLocation={root / 'state'}
SlurmdSpoolDir={root / 'spool'}
SlurmctldPidFile={root / 'slurmctld.pid'}
SlurmdPidFile={root / 'slurmd.pid'}
SlurmctldLogFile={root / 'slurmctld.log'}
SlurmdLogFile={root / 'slurmd.log'}
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/filetxt
JobCompLoc={root / 'jobcomp.txt'}
MpiDefault=none
ReturnToService=2
MinJobAge={MIN_JOB_AGE_S}
SlurmdTimeout=60
NodeName={host} CPUs={cpus} RealMemory={_real_memory_mb()} State=UNKNOWN
PartitionName=debug Nodes={host} Default=YES MaxTime=INFINITE State=UP
""")
    return conf


def _pid(path: Path) -> int | None:
    try:
        return int(path.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def stop_daemons(root: Path) -> None:
    """SIGTERM each daemon named by a pid file under ``root``, then wait for it to go."""
    for name in ("slurmd.pid", "slurmctld.pid", "munge/munged.pid"):
        pid = _pid(root / name)
        if pid is None:
            continue
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:
            continue
        for _ in range(100):
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        print(f"stopped {name.removesuffix('.pid').split('/')[-1]} (pid {pid})", flush=True)
    if SLURM_CONF.exists() and SLURM_CONF.read_text().startswith(CONF_MARKER):
        SLURM_CONF.unlink()


@contextmanager
def cluster(root: Path) -> Iterator[Cluster]:
    """Start munged, slurmctld and slurmd under ``root``; stop them on exit."""
    for sub in ("state", "spool", "munge"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    shutil.chown(root / "munge", "munge", "munge")
    os.chmod(root / "munge", 0o755)
    conf = write_slurm_conf(root)
    try:
        m = root / "munge"
        subprocess.run(["runuser", "-u", "munge", "--", "munged", "--force", f"--socket={m / 'munge.socket'}",
                        f"--pid-file={m / 'munged.pid'}", f"--log-file={m / 'munged.log'}",
                        f"--seed-file={m / 'munged.seed'}"], check=True)
        subprocess.run(["slurmctld", "-f", str(conf)], check=True)
        subprocess.run(["slurmd", "-f", str(conf)], check=True)
        deadline = time.monotonic() + 60
        state = ""
        while time.monotonic() < deadline:
            state = subprocess.run(["sinfo", "-h", "-o", "%t"], capture_output=True, text=True).stdout.strip()
            if state == "idle":
                break
            time.sleep(1)
        check(state == "idle", f"node {socket.gethostname()} idle in SLURM (sinfo: {state!r})")
        yield Cluster(root, conf)
    finally:
        stop_daemons(root)


# --------------------------------------------------------------------------------------------
# Workflow runs and checks
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Run:
    """A ``biasgt run`` started in the background."""

    proc: subprocess.Popen
    workdir: Path
    t0: float

    def wait(self) -> tuple[int, str, float]:
        """Wait for it; returns (exit code, output, seconds); the output is also written beside
        the working folder (``<workdir>.out``)."""
        out, _ = self.proc.communicate()
        seconds = time.monotonic() - self.t0
        (self.workdir.parent / f"{self.workdir.name}.out").write_text(out)
        return self.proc.returncode, out, seconds


def start_run(config: Path, workdir: Path, *args: str, niceness: int = 0) -> Run:
    """Start ``biasgt run`` under ``timeout -k`` (Snakemake ignores SIGTERM while jobs run), at
    ``niceness`` (nice(1)) relative to this script."""
    cmd = ["nice", "-n", str(niceness), "timeout", "-k", "15", str(RUN_TIMEOUT_S), sys.executable, "-m",
           "biasgt.cli", "run", "--config", str(config), "--directory", str(workdir), *args]
    proc = subprocess.Popen(cmd, env={**os.environ, "PYTHONPATH": str(REPO)}, cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return Run(proc, workdir, time.monotonic())


def renice_tree(pid: int, niceness: int) -> None:
    """Set ``niceness`` on ``pid`` and every process descended from it (those already started;
    later children inherit it from their parent)."""
    import psutil  # Snakemake's own dependency

    with contextlib.suppress(psutil.NoSuchProcess):
        root = psutil.Process(pid)
        for process in [root, *root.children(recursive=True)]:
            with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
                process.nice(niceness)


def biasgt_run(config: Path, workdir: Path, *args: str) -> tuple[int, str, float]:
    """``biasgt run`` to its end; returns (exit code, output, seconds)."""
    return start_run(config, workdir, *args).wait()


#: The shipped profile the test runs as it is (a CPU-only node: no GPU for the learning stage).
PROFILE = "slurm-cpu"


def slurm_args(*extra: str) -> list[str]:
    """The SLURM run: a shipped profile with its own resources (no overrides), squeue status polling and
    this cluster's fast status checks."""
    return ["--profile", PROFILE, "--",
            "--slurm-status-command", "squeue",
            "--slurm-init-seconds-before-status-checks", str(INIT_SECONDS),
            "--jobs", "4", "--latency-wait", "5",
            *extra]


_SUBMITTED = re.compile(r"Job (\S+) has been submitted with SLURM jobid (\d+)")
_RULE_BLOCK = re.compile(r"^\s*(?:rule|checkpoint) (\w+):\n((?:\s+\w+: .*\n?)*)", re.M)


@dataclass(frozen=True)
class RuleJob:
    """One job of a rule as Snakemake announced it: its rule, its log's name (the sequence,
    ``dataset``, ``regression_rnn_seed0``...), and Snakemake's uuid of it (Snakemake's id of a
    group job is the uuid of one of its jobs)."""

    rule: str
    name: str
    uuid: str


def _announced_jobs(block: str) -> list[tuple[str, RuleJob]]:
    """(Snakemake job id, job) of each rule announced in one block of Snakemake's log."""
    from snakemake.common import get_uuid  # Snakemake's own job uuid (snakemake.jobs.Job.uuid)

    jobs = []
    for m in _RULE_BLOCK.finditer(block):
        fields = dict(re.findall(r"^\s+(\w+): (.*)$", m.group(2), re.M))
        if "jobid" not in fields:
            continue
        wildcards = sorted(w.replace("=", ":", 1) for w in fields.get("wildcards", "").split(", ") if w)
        log = fields.get("log", "").split(",")[0].split(" ")[0]
        jobs.append((fields["jobid"], RuleJob(m.group(1), Path(log).stem if log else "dataset",
                                              str(get_uuid(f"{m.group(1)}:{','.join(wildcards)}")))))
    return jobs


def submitted_jobs(workdir: Path) -> list[tuple[str, str, str]]:
    """(rule, job name, SLURM job id) of every rule job the last Snakemake run submitted, a job of a
    group job (several rules in one SLURM job) under its group's SLURM id."""
    log = sorted((workdir / ".snakemake" / "log").glob("*.snakemake.log"))[-1].read_text()
    by_id: dict[str, list[RuleJob]] = {}  # Snakemake's id of a submitted (group) job -> its rule jobs
    for block in re.split(r"\n(?=\[[A-Z][a-z]{2} )", log):
        announced = _announced_jobs(block)
        if re.search(r"^\[.*\] Group job \w+ \(jobs in lexicogr", block, re.M):
            members = [job for _, job in announced]
            for job in members:
                by_id[job.uuid] = members
        else:
            for jobid, job in announced:
                by_id[jobid] = [job]
    out = []
    for key, slurm_id in _SUBMITTED.findall(log):
        if key not in by_id:
            raise CheckFailed(f"Snakemake's log: submitted job {key} (SLURM job {slurm_id}) was never announced")
        out += [(job.rule, job.name, slurm_id) for job in by_id[key]]
    return out


def check_slurm_jobs(c: Cluster, workdir: Path, jobs: list[tuple[str, str, str]], state: str) -> None:
    """Each job's own log names its SLURM job id; SLURM's completion log lists it in ``state``."""
    finished = c.finished_jobs()
    folders = {"recover": "recovery", "interpolate": "interpolation", "validate": "validation",
               "train": "training", "evaluate": "evaluation", "evaluate_reference": "evaluation",
               "training_report": "report", "dataset_report": "report"}
    for rule, name, slurm_id in jobs:
        job_log = workdir / "logs" / folders.get(rule, rule) / f"{name}.log"
        text = job_log.read_text() if job_log.exists() else ""
        check(f"SLURM job {slurm_id}" in text and finished.get(slurm_id) == state,
              f"{rule} {name}: SLURM job {slurm_id}, {finished.get(slurm_id)}, named in {job_log.relative_to(workdir)}")


def same_content(a: Path, b: Path) -> bool:
    """Byte-equal, or equal but for the fields of ALLOWED_DIFFERENCES."""
    if a.read_bytes() == b.read_bytes():
        return True
    if a.name == "recovery.json":
        def strip(p: Path) -> object:
            return {k: v for k, v in json.loads(p.read_text()).items() if k not in ("runtime_s", "timings_s")}
        return strip(a) == strip(b)
    if a.name == "report.html":
        timing = re.compile(r"generated \S+ \S+ UTC|recovery runtime \[s\]</td>\n<td class=\"num\">[0-9.e+-]+")
        return timing.sub("", a.read_text()) == timing.sub("", b.read_text())
    return False


def _holds_wall_clock_times(path: Path) -> bool:
    """A trained run, an evaluation folder or the training report: they record training and sampling
    times (run.json, metrics.csv, checkpoints, summary.json, training.html); Table I does not."""
    parts = path.parts
    if parts[:2] == ("results", "evaluation") and path.name in ("table.csv", "table.md"):
        return False
    return parts[:2] in (("results", "training"), ("results", "evaluation")) or path.name == "training.html"


def compare_results(local: Path, remote: Path) -> int:
    """Check that both runs wrote the same files with the same content; returns the file count."""
    def files(root: Path) -> set[Path]:
        # the dataset page lists its own config's sequences (the SLURM config has one more, the broken one)
        return {p.relative_to(root) for p in (root / "results").rglob("*")
                if p.is_file() and p.name not in (".snakemake_timestamp", "index.html")}

    mine, theirs = files(local), files(remote)
    check(mine == theirs, f"same {len(mine)} files under results/ (only local: {sorted(map(str, mine - theirs))[:3]}, "
                          f"only SLURM: {sorted(map(str, theirs - mine))[:3]})")
    exact = sum((local / p).read_bytes() == (remote / p).read_bytes() for p in mine)
    compared = [p for p in mine if not _holds_wall_clock_times(p)]
    differing = sorted(str(p) for p in compared if not same_content(local / p, remote / p))
    check(not differing, f"same content: {exact} of {len(mine)} files byte-identical, the others equal "
                         f"but for {'; '.join(f'{k}: {v}' for k, v in ALLOWED_DIFFERENCES.items())}"
                         + (f"; DIFFERENT: {differing[:5]}" if differing else ""))
    for key in ("recovery/sim_a/bias.csv", "validation/sim_a/validation.json", "windows/dataset/manifest.json",
                "evaluation/table.csv", "evaluation/table.md"):
        check((local / "results" / key).read_bytes() == (remote / "results" / key).read_bytes(),
              f"results/{key} byte-identical")
    return len(mine)


def corrupt_recording(folder: Path) -> tuple[Path, Path]:
    """Simulate a recording into ``folder`` with ``biasgt simulate`` and cut its IMU file to the
    header (a recording that lost its samples); returns (the IMU file, a copy of the good one)."""
    subprocess.run([sys.executable, "-m", "biasgt.cli", "simulate", "--duration", "10", "--seed", "4",
                    "--preset", "handheld", "--pose-format", "mocap", str(folder)],
                   env={**os.environ, "PYTHONPATH": str(REPO)}, cwd=REPO, check=True, capture_output=True)
    imu = folder / "mav0" / "imu0" / "data.csv"
    good = shutil.copy(imu, folder.parent / "good_imu.csv")
    imu.write_text(imu.read_text().splitlines(keepends=True)[0])
    return imu, Path(good)


def slurm_ids(jobs: list[tuple[str, str, str]]) -> list[str]:
    """The distinct SLURM job ids of ``jobs``, in submission order (a group job's rules share one)."""
    return list(dict.fromkeys(slurm_id for _, _, slurm_id in jobs))


def check_failed_ingest(c: Cluster, remote: Path, rc: int, out: str, jobs: list[tuple[str, str, str]]) -> None:
    """The corrupt sequence: its job (its group of stages) FAILED in SLURM twice (retries: 1) at
    ingest, one-line error naming ingest, nothing of the sequence left."""
    failed = [job for job in jobs if job[1] == "broken"]
    ids = slurm_ids(failed)
    check(rc == 2 and "rule 'ingest' (sequence=broken) failed" in out and "logs/ingest/broken.log" in out,
          f"biasgt run exits 2 naming the failed rule and its log: {out.strip().splitlines()[-1][:200]}")
    check(len(ids) == 2 and all(("ingest", "broken", i) in failed for i in ids),
          f"the corrupt sequence's ingest was submitted twice (profile: retries 1), in SLURM jobs {ids}")
    # The job log is rewritten by each attempt: it names the last one.
    check_slurm_jobs(c, remote, [("ingest", "broken", ids[-1])], "FAILED")
    check(c.finished_jobs().get(ids[0]) == "FAILED", f"first attempt, SLURM job {ids[0]}: FAILED")
    left = sorted(str(p.relative_to(remote)) for p in (remote / "results").glob("*/broken"))
    check(not left, f"nothing of the corrupt sequence under results/ (no half-written output): {left}")


def rerun_after_repair(c: Cluster, config: Path, remote: Path, imu: Path, good_imu: Path) -> list[tuple[str, str, str]]:
    """Repair the corrupt file and rerun: only that sequence's jobs run, the rest is untouched."""
    # every file but the dataset page, which a changed sequence rewrites by design
    before = {p: p.stat().st_mtime_ns for p in (remote / "results").rglob("*")
              if p.is_file() and p.name != "index.html"}
    shutil.copy(good_imu, imu)
    rc, out, seconds = biasgt_run(config, remote, *slurm_args())
    jobs = submitted_jobs(remote)
    check(rc == 0 and sorted(r for r, n, _ in jobs if n == "broken") == sorted(BROKEN_RULES)
          and sorted(r for r, n, _ in jobs if n != "broken") == ["dataset_report"],
          f"rerun after the repair: exit {rc} in {seconds:.0f} s, the repaired sequence's {len(jobs)} jobs and the "
          "dataset page only "
          f"(SLURM jobs {slurm_ids(jobs)})")
    check_slurm_jobs(c, remote, jobs, "COMPLETED")
    check(all(p.stat().st_mtime_ns == t for p, t in before.items()), f"the {len(before)} finished files untouched")
    return jobs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder (its path is printed)")
    args = parser.parse_args(argv)
    t_start = time.monotonic()
    tmp = Path(tempfile.mkdtemp(prefix="biasgt-slurm-"))
    os.chmod(tmp, 0o755)  # munged checks that the socket's parent folders are not world-writable
    print(f"working folder: {tmp}", flush=True)
    local = None
    try:
        ensure_packages()
        imu, good_imu = corrupt_recording(tmp / "broken")
        (tmp / "local.yaml").write_text(CONFIG + LEARNING)
        (tmp / "slurm.yaml").write_text(CONFIG + BROKEN + LEARNING)
        # The local reference runs alongside, at the lowest priority: the SLURM run's jobs keep the
        # cores they need, and the local run takes them while the SLURM run waits for the plugin's
        # next status check. Once the SLURM run has ended it goes back to this script's priority.
        local = start_run(tmp / "local.yaml", tmp / "local", "--cores", "2", niceness=19)
        with cluster(tmp / "slurm") as c:
            remote = tmp / "remote"
            rc, out, seconds = biasgt_run(tmp / "slurm.yaml", remote, *slurm_args())
            jobs = submitted_jobs(remote)
            good = [job for job in jobs if job[1] != "broken"]
            print(f"SLURM run: exit {rc} in {seconds:.0f} s, {len(jobs)} jobs in {len(slurm_ids(jobs))} SLURM jobs",
                  flush=True)
            check(len(good) == GOOD_JOBS and len(slurm_ids(good)) == GOOD_SLURM_JOBS,
                  f"{GOOD_JOBS} jobs of the good sequences and the learning stage (3 x 6 stages + windows + train, "
                  f"evaluate, table, training_report; 'all' is local) in {GOOD_SLURM_JOBS} SLURM jobs (the "
                  f"profile's groups): {len(good)} in {len(slurm_ids(good))}")
            check_slurm_jobs(c, remote, good, "COMPLETED")
            check_failed_ingest(c, remote, rc, out, jobs)
            # the cluster's jobs are done: the local run no longer yields (on a busy machine it
            # would otherwise starve at nice 19 until its timeout)
            renice_tree(local.proc.pid, os.getpriority(os.PRIO_PROCESS, 0))
            local_rc, _, local_s = local.wait()
            check(local_rc == 0, f"local run (alongside): exit {local_rc} in {local_s:.0f} s")
            n_files = compare_results(tmp / "local", remote)
            rerun = rerun_after_repair(c, tmp / "slurm.yaml", remote, imu, good_imu)
        print(f"PASS: {len(jobs)} + {len(rerun)} jobs in {len(slurm_ids(jobs))} + {len(slurm_ids(rerun))} SLURM "
              f"jobs, {n_files} result files equal to the local run's, failure and rerun checked; "
              f"{time.monotonic() - t_start:.0f} s in all", flush=True)
        return 0
    except (CheckFailed, subprocess.CalledProcessError) as exc:
        print(f"FAILED: {exc} (outputs under {tmp})", flush=True)
        args.keep = True
        return 1
    finally:
        if local is not None and local.proc.poll() is None:  # a check failed before it ended
            local.proc.terminate()
            local.proc.wait(60)
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
