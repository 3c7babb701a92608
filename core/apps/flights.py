"""The flights of an experiment: flown one after another, or as Ray tasks; found again on resume.

An experiment lists its flights first (:class:`Flight`: a mission and its ``--set`` overrides),
then :func:`fly_all` flies those not flown yet and returns one record per flight, in the order
given, for the experiment's tables:

* **As Ray tasks** (``--executor ray``, the default when Ray is installed): each flight a task of
  one CPU in its own worker process, on a local Ray (``ray.init()`` on this machine: as many
  flights at once as it has cores) or on a cluster (``--address ray://HEAD:10001``, or ``auto``
  inside one). Ray is an optional extra, ``pip install 'amslam[ray]'``. On a cluster the run
  folders are written on the node that flew them: give ``--out`` a folder every node shares, or
  only the records come back.
* **Serially** in this process (``--executor serial``; the default without Ray installed).
* **Resumable**: every finished flight leaves ``flights/<key>.json`` in the experiment folder
  (its record, written atomically). ``--resume FOLDER`` flies in that experiment folder again
  and skips each flight whose record is there, so an experiment stopped half-way (a killed
  process, a lost node) goes on where it stopped. The key is the mission as given and the sorted
  overrides, so the same command finds the same flights. Each record notes the code it was
  flown with (:func:`source_revision`); a resume says how many kept flights were flown with
  other code (their figures stand as flown: re-using unchanged flights is legitimate, mixing
  changed ones silently is not).

A flight that raises is recorded with verdict ``failed`` and its error, and the others go on:
nothing already flown is lost to one bad flight. Progress is one line per finished flight.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from amslam.errors import AmslamError
from amslam.registry import Registry, build_plugin_manager
from amslam.rundir import new_folder, write_atomically

RAY_HINT = "Ray is not installed: pip install 'amslam[ray]' (or fly with --executor serial)"
EXECUTORS = ("ray", "serial")


@dataclass(frozen=True)
class Flight:
    """One flight of an experiment: a mission (file or packaged name) and its overrides."""

    mission: str
    overrides: tuple[str, ...]

    @property
    def key(self) -> str:
        """The flight's name in the experiment folder: the same command gives the same key."""
        spec = self.mission
        if Path(spec).is_file():  # a file given by two relative paths is one mission
            spec = str(Path(spec).resolve())
        text = json.dumps([spec, sorted(self.overrides)])
        return hashlib.sha1(text.encode()).hexdigest()[:16]

    def label(self) -> str:
        return " ".join(self.overrides) or Path(self.mission).stem


def code_note(records: Sequence[dict[str, Any]]) -> str:
    """The line under a table saying which code its flights were flown with (records' ``code``):
    a table is "at the final code" only if this names one commit, and a resumed folder's kept
    flights may have been flown with another."""
    counts: dict[str, int] = {}
    for r in records:
        code = str(r.get("code", "unrecorded"))
        counts[code] = counts.get(code, 0) + 1
    parts = [
        f"{code} ({n} flight{'s' if n != 1 else ''})"
        for code, n in sorted(counts.items(), key=lambda kv: -kv[1])
    ]
    return f"\nFlown with code: {', '.join(parts) or 'no flights'}.\n"


def source_revision() -> str:
    """The code flights are flown with: the git commit of amslam's source checkout, with
    ``+changes`` when its tracked files differ from it; ``amslam X.Y.Z`` when amslam is not run from
    its own checkout (an installed wheel)."""
    import subprocess

    from amslam import __version__

    package = Path(__file__).resolve().parents[1]

    def git(*args: str) -> str:
        out = subprocess.run(["git", "-C", str(package), *args], capture_output=True, text=True, timeout=20)
        if out.returncode:
            raise OSError(out.stderr.strip())
        return out.stdout.strip()

    try:
        top = Path(git("rev-parse", "--show-toplevel")).resolve()
        if top / "core" != package:  # a checkout of something else that happens to hold the install
            raise OSError("not amslam's checkout")
        changed = git("status", "--porcelain", "--untracked-files=no")
        return git("rev-parse", "--short=12", "HEAD") + ("+changes" if changed else "")
    except (OSError, subprocess.SubprocessError):
        return f"amslam {__version__}"


def flight_arguments(parser: argparse.ArgumentParser) -> None:
    """``--executor``, ``--address``, ``--resume``: how an experiment's flights are run."""
    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        help="ray: each flight a Ray task, on a local Ray unless --address (the default when Ray is "
        "installed); serial: one flight after another in this process (the default without Ray)",
    )
    parser.add_argument("--ray", action="store_true", help="the same as --executor ray")
    parser.add_argument("--address", help="Ray cluster for --executor ray (ray://HOST:PORT, or auto)")
    parser.add_argument(
        "--resume", metavar="FOLDER", help="an experiment folder to go on in: its finished flights are kept"
    )


def ray_installed() -> bool:
    import importlib.util

    return importlib.util.find_spec("ray") is not None


@dataclass(frozen=True)
class FlightRunner:
    """How :func:`fly_all` runs flights: serially or on Ray (``address`` None: a local Ray)."""

    ray: bool = False
    address: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> FlightRunner:
        """The runner the command line asks for; Ray when nothing is said and it is installed.

        Raises:
            AmslamError: ``--ray`` with ``--executor serial``, ``--address`` with a serial
                executor, or ``--executor ray`` without Ray installed.
        """
        # A parser without --executor (the benchmark scripts, each with its own --ray) flies
        # serially unless asked; an experiment's command line that says nothing flies on Ray when
        # it is installed.
        chooses = hasattr(args, "executor")
        executor = args.executor if chooses else None
        if getattr(args, "ray", False):
            if executor == "serial":
                raise AmslamError("--ray and --executor serial disagree: give one of them")
            executor = "ray"
        address = getattr(args, "address", None)
        if executor is None:
            executor = "ray" if chooses and (address or ray_installed()) else "serial"
        if address and executor != "ray":
            raise AmslamError(
                "--address names a Ray cluster: it needs the Ray executor (--executor ray, or --ray)"
            )
        if executor == "ray" and not ray_installed():
            raise AmslamError(RAY_HINT)
        return cls(executor == "ray", address)


#: flights one after another in this process
SERIAL = FlightRunner()


def experiment_folder(out: Path, experiment: str, mission: str, resume: str | None = None) -> Path:
    """A new experiment folder with its ``runs`` folder, or the one to resume (checked)."""
    if resume:
        folder = Path(resume)
        if not (folder / "runs").is_dir():
            raise AmslamError(f"--resume {resume}: not an experiment folder (it has no runs/ folder)")
        return folder
    name = f"{experiment}-{Path(mission).stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    folder = new_folder(Path(out), name, "an experiment folder")
    (folder / "runs").mkdir()
    return folder


def fly_all(
    flights: Sequence[Flight],
    folder: Path,
    runner: FlightRunner = SERIAL,
    log: Callable[[str], None] = print,
    registry: Registry | None = None,
) -> list[dict[str, Any]]:
    """Fly the flights not flown yet in ``folder``; every flight's record, in the order given.

    Serial flights use ``registry`` (default: the installed plugins); a Ray worker loads the
    installed plugins itself (a registry holds modules, which do not travel between processes).

    A record is ``{"overrides", "run_dir", "metrics", "wall_s", "code"}``; a flight that raised has
    ``metrics == {"verdict": "failed", "error": ...}`` and ``run_dir`` None.
    """
    records_dir = Path(folder) / "flights"
    records_dir.mkdir(exist_ok=True)
    done: dict[str, dict[str, Any]] = {}
    for f in flights:
        path = records_dir / f"{f.key}.json"
        if path.exists() and f.key not in done:
            try:
                done[f.key] = json.loads(path.read_text())
            except (OSError, ValueError):
                continue  # a record that does not read is flown again
    todo = list({f.key: f for f in flights if f.key not in done}.values())
    total = len(todo)
    code = source_revision()
    if len(done):
        log(f"  {len(done)} flight(s) already flown in {folder}, {total} to fly")
        other = [str(r.get("code", "an unrecorded version")) for r in done.values() if r.get("code") != code]
        if other:
            log(
                f"  {len(other)} of them flown with other code ({', '.join(sorted(set(other)))}), this is"
                f" {code}: their figures stand as flown"
            )
    finished = 0

    def record(flight: Flight, rec: dict[str, Any]) -> None:
        nonlocal finished
        finished += 1
        rec = {**rec, "code": code}
        done[flight.key] = rec
        write_atomically(records_dir / f"{flight.key}.json", json.dumps(rec, indent=2, default=str) + "\n")
        verdict = rec["metrics"].get("verdict", "?")
        where = rec["run_dir"] or rec["metrics"].get("error", "")
        log(f"  [{finished}/{total}] {flight.label():<60} {verdict:<12} ({rec['wall_s']:.0f} s) {where}")

    runs = Path(folder) / "runs"
    if runner.ray and todo:
        _fly_on_ray(todo, runs, runner.address, record)
    else:
        for flight in todo:
            record(flight, fly_one(flight.mission, flight.overrides, str(runs), registry))
    return [done[f.key] for f in flights]


def fly_benchmark(
    flights: Sequence[Flight], args: argparse.Namespace, benchmark: str
) -> tuple[Path, list[dict[str, Any]]] | None:
    """A benchmark script's flights: a new folder ``<benchmark>-buildings-<time>`` under
    ``args.out`` (or ``args.resume``), flown as ``args`` says (``--executor``, ``--address``), one
    progress line per flight on stdout. None once the error is printed on stderr (``--executor
    ray`` without Ray installed, ``--address`` with a serial executor, an ``--resume`` that is no
    benchmark folder)."""
    try:
        folder = experiment_folder(Path(args.out), benchmark, "buildings", args.resume)
        print(f"benchmark folder: {folder} ({len(flights)} flights)", flush=True)
        records = fly_all(flights, folder, FlightRunner.from_args(args), lambda line: print(line, flush=True))
    except AmslamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    return folder, records


def fly_one(
    mission: str, overrides: Sequence[str], runs: str, registry: Registry | None = None
) -> dict[str, Any]:
    """One flight in this process (a Ray worker's too): its record; an exception is recorded."""
    from amslam.mission import load_mission
    from amslam.runner import Runner  # the runner (py_trees, threads) is imported when a flight starts

    overrides = list(overrides)
    started = time.perf_counter()
    try:
        registry = registry or build_plugin_manager()
        result = Runner(load_mission(mission, registry, overrides), registry, Path(runs)).run()
    except Exception as exc:  # one flight's failure is that flight's row, not the experiment's end
        return _failed(overrides, exc, time.perf_counter() - started)
    took = time.perf_counter() - started
    return {"overrides": overrides, "run_dir": str(result.run_dir), "metrics": result.metrics, "wall_s": took}


def _failed(overrides: Sequence[str], exc: BaseException, took: float) -> dict[str, Any]:
    metrics = {"verdict": "failed", "error": f"{type(exc).__name__}: {exc}"}
    return {"overrides": list(overrides), "run_dir": None, "metrics": metrics, "wall_s": took}


def _fly_on_ray(
    todo: list[Flight], runs: Path, address: str | None, record: Callable[[Flight, dict], None]
) -> None:
    try:
        import ray
    except ImportError:
        raise AmslamError(RAY_HINT) from None
    started_here = not ray.is_initialized()
    if started_here:
        # A local Ray (address None) starts its own head; its dashboard and log forwarding are
        # not wanted in a terminal that prints one line per flight.
        ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(fly_one)
        pending = {
            task.remote(f.mission, list(f.overrides), str(runs.resolve())): (f, time.perf_counter())
            for f in todo
        }
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            flight, started = pending.pop(ready[0])
            try:
                rec = ray.get(ready[0])
            except Exception as exc:  # the worker died (killed, out of memory): that flight failed
                rec = _failed(flight.overrides, exc, time.perf_counter() - started)
            record(flight, rec)
    finally:
        if started_here:
            ray.shutdown()
