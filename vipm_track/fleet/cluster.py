"""A fleet of drives on Dask (``dask.distributed``): one task per drive
(:func:`~vipm_track.fleet.drive_run.run_drive`) on a local cluster of processes or on an
existing scheduler, the summary table written as the drives finish.

Every worker writes its drive's tables into ``OUT/drive=NAME/`` itself, so on several
machines OUT (and the drives) must be on a file system they all mount at the same path.
A worker that dies takes its task with it: the scheduler runs it again elsewhere, up to
``retries`` times, and then the drive is a row with the error. Drives whose ``done.json``
holds the same input hash and vipm-track version, their tables all there, are not run again
(their row is reused), so a fleet that was stopped resumes where it stopped.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import os
import re
import signal
import socket
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import dask
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
from distributed import Client, LocalCluster, Security, WorkerPlugin, as_completed
from distributed import comm as dask_comm
from distributed.comm.registry import get_backend

from ..errors import InputError, printable
from ..progress import progress_bar, redraw_interval_s
from ..table import format_value
from ..workers import THREADS_ENV
from .drive_progress import FleetProgress, progress_topic
from .drive_run import (
    DONE_FILE,
    FleetSettings,
    done_row,
    drive_folder,
    remove_outputs,
    run_drive,
)
from .drives import DriveSpec


def worker_environ(workers: int) -> dict[str, int]:
    """Environment of a local cluster's ``workers`` worker processes: Dask's default without
    its ``MALLOC_TRIM_THRESHOLD_=65536``, which hands every freed block back to the system and
    made the estimator, which allocates many short-lived arrays per pair, half as fast in a
    worker; one BLAS / OpenMP thread each, as a worker runs one drive at a time, and the
    machine's cores shared out as patch-correlation threads (one each where workers fill
    the cores)."""
    threads = max(1, (os.cpu_count() or 1) // max(workers, 1))
    return {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1,
            THREADS_ENV: threads}

#: seconds a running scheduler (``--scheduler``) has to answer before the fleet gives up
CONNECT_TIMEOUT_S = 10.0
#: Dask's address schemes that are a TCP connection to HOST:PORT underneath
_TCP_SCHEMES = frozenset({"tcp", "tls", "ws", "wss"})

#: fleet_summary columns, in order (see docs/fleet.md)
SUMMARY_COLUMNS: tuple[str, ...] = (
    "drive", "vehicle", "started", "status", "frames", "share_ok", "duration_s", "t_start_s",
    "mount_pitch_deg", "mount_pitch_std_deg", "mount_pitch_ci95_low_deg",
    "mount_pitch_ci95_high_deg", "pitch_drift_deg_per_min",
    "mount_roll_deg", "mount_roll_std_deg", "mount_roll_ci95_low_deg",
    "mount_roll_ci95_high_deg", "roll_drift_deg_per_min",
    "mount_height_m", "mount_height_std_m", "mount_height_ci95_low_m",
    "mount_height_ci95_high_m", "height_drift_m_per_min",
    "nominal_pitch_deg", "nominal_roll_deg", "nominal_height_m", "wheel_speed",
    "monitor_verdict", "first_recalibrate_s", "monitor_states", "warnings", "wall_s",
    "skipped", "worker", "input_hash",
)
SUMMARY_TEXT_COLUMNS = frozenset({"drive", "vehicle", "started", "status", "monitor_verdict",
                                  "monitor_states", "worker", "input_hash", "wheel_speed",
                                  "skipped", "warnings"})
#: the tables' partitioning, ``drive`` read as text: inferred, drives "01" and "1" (KITTI's
#: "00", "07") were both the number 1
DRIVE_PARTITIONING = ds.partitioning(pa.schema([("drive", pa.string())]), flavor="hive")


def run_fleet(
    specs: Sequence[DriveSpec],
    out: str | Path,
    settings: FleetSettings | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    processes: bool = True,
    retries: int = 2,
    progress: bool = True,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    connect_timeout_s: float | None = None,
) -> list[dict[str, Any]]:
    """Run every drive of ``specs`` as a Dask task and write ``OUT/fleet_summary.csv`` and
    ``.parquet`` (one row per drive, in ``specs``' order; rewritten as each drive ends, so an
    interrupt keeps the finished ones). ``scheduler``: the address of a running Dask
    scheduler (:func:`connect_scheduler`, within ``connect_timeout_s`` seconds; None:
    :data:`CONNECT_TIMEOUT_S`); else a ``LocalCluster`` of ``workers`` single-threaded
    workers (processes, or threads of this process where ``processes`` is false).
    ``on_row`` is called with each drive's row as it ends. Returns the rows. InputError
    where ``scheduler`` is no address or nothing there answers as a Dask scheduler."""
    settings = settings or FleetSettings()
    if scheduler:
        scheduler_address(scheduler)
    timeout_s = CONNECT_TIMEOUT_S if connect_timeout_s is None else connect_timeout_s
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[str, dict[str, Any]] = {}
    start = time.perf_counter()
    try:
        _run_all(specs, out, settings, workers, scheduler, timeout_s, processes, retries,
                 progress, on_row, rows)
    except KeyboardInterrupt:
        # the cluster is closed by now: a drive that finished as the interrupt came has its
        # done.json; every other unfinished drive is a row saying so (run again to resume)
        for spec in specs:
            if spec.drive not in rows:
                finished = _finished_row(spec, out, settings)
                if finished is None:
                    # a worker killed mid-drive left tables that no done.json vouches for
                    # (a `drive=*` glob read them) or an empty partition
                    remove_outputs(drive_folder(out, spec.drive))
                row = finished or {
                    "drive": spec.drive, "vehicle": spec.vehicle, "started": spec.started,
                    "status": f"error: {spec.problem}" if spec.problem else
                              "error: interrupted before the drive finished (run again with "
                              "the same --out to resume)", "skipped": False}
                rows[spec.drive] = row
                if on_row is not None:
                    on_row(row)
        write_summary(out, [rows[s.drive] for s in specs if s.drive in rows])
        raise
    ordered = [rows[s.drive] for s in specs if s.drive in rows]
    if progress:
        ok = sum(r.get("status") == "ok" for r in ordered)
        print(f"vipm-track fleet: {ok} of {len(specs)} drives ok in "
              f"{time.perf_counter() - start:.1f} s → {out / 'fleet_summary.csv'}",
              file=sys.stderr)
    return ordered


def _finished_row(spec: DriveSpec, out: Path, settings: FleetSettings) -> dict[str, Any] | None:
    """The row of a drive whose ``done.json`` holds its current input hash, else None."""
    try:
        if spec.problem:
            return None
        row = done_row(drive_folder(out, spec.drive), spec.input_hash(settings.key()))
    except Exception:  # unreadable inputs: the drive is not done
        return None
    return None if row is None else {**row, "skipped": False}


def _run_all(specs: Sequence[DriveSpec], out: Path, settings: FleetSettings, workers: int,
             scheduler: str | None, timeout_s: float, processes: bool, retries: int,
             progress: bool, on_row: Callable[[dict[str, Any]], None] | None,
             rows: dict[str, dict[str, Any]]) -> None:
    with dask.config.set({"distributed.scheduler.allowed-failures": retries,
                          "distributed.nanny.pre-spawn-environ": worker_environ(workers)}), \
            _client(workers, scheduler, timeout_s, processes) as client:
        topic = progress_topic() if progress else None
        futures = {client.submit(run_drive, spec, str(out), settings, topic,
                                 key=f"drive-{spec.drive}", pure=False, retries=retries): spec
                   for spec in specs}
        bar = progress_bar(total=len(futures), desc="fleet", unit="drive", disable=not progress)
        running = FleetProgress()
        if topic is not None:
            client.subscribe_topic(topic, _show_running(running, bar))
        try:
            for future in as_completed(futures):
                spec = futures[future]
                running.finished(spec.drive)
                bar.set_postfix_str(running.text(), refresh=False)
                try:
                    row = future.result()
                except Exception as exc:  # the worker died `retries` times, or was lost
                    row = {"drive": spec.drive, "vehicle": spec.vehicle, "started": spec.started,
                           "status": f"error: {type(exc).__name__}: {exc}", "skipped": False}
                rows[spec.drive] = row
                bar.update(1)
                if progress:
                    bar.write(drive_line(row), file=sys.stderr)
                if on_row is not None:
                    on_row(row)
                write_summary(out, [rows[s.drive] for s in specs if s.drive in rows])
        finally:
            bar.close()
            for future in futures:
                future.cancel()
            if topic is not None:
                with contextlib.suppress(Exception):  # a lost scheduler: nothing to undo
                    client.unsubscribe_topic(topic)


def _show_running(running: FleetProgress, bar: Any) -> Callable[[tuple], None]:
    """The progress events' handler: tallies them in ``running`` and shows its text beside
    ``bar`` (redrawn at most every ``redraw_interval_s()``)."""
    last = [-float("inf")]
    interval = redraw_interval_s()

    def handler(event: tuple) -> None:
        running.on_event(event)
        now = time.monotonic()
        if now - last[0] >= interval:
            last[0] = now
            bar.set_postfix_str(running.text())

    return handler


def _client(workers: int, scheduler: str | None, timeout_s: float, processes: bool) -> Any:
    """A context giving the client: of ``scheduler``, or of a new local cluster."""
    if scheduler:
        return connect_scheduler(scheduler, timeout_s)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=processes,
                           dashboard_address=None)
    client = Client(cluster)
    if processes:
        client.register_plugin(_IgnoreSigint(), name="vipm-track-ignore-sigint")
    return _ClosingClient(client, cluster)


def scheduler_address(address: str) -> str:
    """``address`` with its scheme (``tcp://`` where it names none), parsed as Dask parses
    it. InputError naming it where Dask could not connect to it: an unknown scheme, no
    host, no port or one out of range (``inproc://`` addresses, of a scheduler in this
    process, have neither)."""
    try:
        scheme, location = dask_comm.parse_address(address)
        try:
            host, port = get_backend(scheme).get_address_host_port(location)
        except NotImplementedError:  # inproc: no host and port to check
            host, port = "inproc", 1
        if not host:
            raise ValueError("no host")
        if not 0 < port < 65536:
            raise ValueError(f"port {port} is not in 1-65535")
    except ValueError as exc:
        raise InputError(f"--scheduler {printable(address, 200)}: not a scheduler address "
                         f"({printable(exc, 200)}); expected tcp://HOST:PORT") from None
    return dask_comm.unparse_address(scheme, location)


def connect_scheduler(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Client:
    """A client of the Dask scheduler running at ``address`` (:func:`scheduler_address`),
    connected within about ``timeout_s`` seconds. InputError ``--scheduler ADDRESS: cannot
    connect (why)`` where nothing listens there, its host is unknown or unreachable, or
    what answers there is not a Dask scheduler (``not a scheduler address`` where it is not
    one)."""
    full = scheduler_address(address)
    where = f"--scheduler {printable(address, 200)}: cannot connect"
    scheme, location = dask_comm.parse_address(full)
    if scheme in _TCP_SCHEMES:
        _reach(get_backend(scheme).get_address_host_port(location), timeout_s, where)
        _handshake(full, timeout_s, where)
    try:
        return Client(full, timeout=timeout_s)
    except Exception as exc:  # anything that ends the connection, said on one line
        raise InputError(f"{where} ({_connect_error(exc, timeout_s)})") from None


def _reach(host_port: tuple[str, int], timeout_s: float, where: str) -> None:
    """A TCP connection to ``host_port``, closed again; InputError ``WHERE (why)`` with the
    OS's reason where none is made (Dask's connect retries a refused one until its timeout
    and then may name the timeout alone)."""
    try:
        socket.create_connection(host_port, timeout=timeout_s).close()
    except TimeoutError:
        raise InputError(f"{where} ({printable(host_port[0], 200)} did not answer within "
                         f"{timeout_s:g} s)") from None
    except OSError as exc:
        raise InputError(f"{where} ({printable(exc.strerror or type(exc).__name__, 200)})") \
            from None


def _handshake(address: str, timeout_s: float, where: str) -> None:
    """Dask's handshake with ``address``, bounded by ``timeout_s`` + 1 s in all: Dask's own
    timeout bounds reaching the host, not the reply, and a server that is not a Dask
    scheduler (a web server) may never send one, or send bytes Dask misreads as frame
    lengths of exabytes. InputError ``WHERE (why)`` where it fails."""
    async def handshake() -> None:
        security = Security().get_connection_args("client")
        comm = await asyncio.wait_for(
            dask_comm.connect(address, timeout=timeout_s, **security), timeout_s + 1.0)
        await comm.close()

    # its own thread and event loop: the caller may be running one (a notebook)
    with ThreadPoolExecutor(1, thread_name_prefix="vipm-track-handshake") as pool:
        try:
            pool.submit(asyncio.run, handshake()).result()
        except OSError as exc:  # TimeoutError among them
            raise InputError(f"{where} ({_connect_error(exc, timeout_s)})") from None
        except Exception as exc:  # its reply is no Dask message
            raise InputError(f"{where} (what answers there is not a Dask scheduler: "
                             f"{type(exc).__name__} reading its reply)") from None


def _connect_error(exc: BaseException, timeout_s: float) -> str:
    """Why a connection failed, in words: the OS's reason (``Connection refused``, ``Name or
    service not known``), or that nothing answered in time."""
    root = exc
    while root.__cause__ is not None and not isinstance(root, TimeoutError):
        root = root.__cause__
    if isinstance(root, TimeoutError):
        return f"no Dask scheduler answered within {timeout_s:g} s"
    if isinstance(root, OSError) and root.strerror:
        return printable(root.strerror, 200)
    text = re.sub(r"^in <[^>]*>: ", "", str(root))  # Dask names its connector object first
    return printable(f"{type(root).__name__}: {text}" if text else type(root).__name__, 300)


class _IgnoreSigint(WorkerPlugin):
    """Makes a local cluster's worker processes ignore SIGINT: Ctrl-C reaches the whole
    process group, and this process, not each worker, ends the run (closing the cluster);
    a worker interrupted itself printed its tracebacks."""

    def setup(self, worker: Any) -> None:
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:  # not the worker process's main thread: leave it
            pass


class _ClosingClient:
    """A client whose context also closes the local cluster it runs on."""

    def __init__(self, client: Client, cluster: LocalCluster) -> None:
        self.client, self.cluster = client, cluster

    def __enter__(self) -> Client:
        return self.client

    def __exit__(self, *exc: object) -> None:
        self.client.close()
        self.cluster.close()


def drive_line(row: dict[str, Any]) -> str:
    """One line on a finished drive: its status, frames, mount and wall time (and why an
    earlier run's outputs were not reused)."""
    name = row.get("drive", "?")
    if row.get("status") != "ok":
        return f"drive {name}: {row.get('status')}"
    how = "unchanged, skipped" if row.get("skipped") else f"{row.get('wall_s', 0):.1f} s"
    if row.get("redone"):
        how += f", {row['redone']}, redone"
    return (f"drive {name}: ok, {row['frames']} frames ({100 * row['share_ok']:.0f} % ok), "
            f"mount pitch {row['mount_pitch_deg']:.3f}° roll {row['mount_roll_deg']:.3f}° "
            f"height {row['mount_height_m']:.4f} m, monitor {row['monitor_verdict']} ({how})")


def write_summary(out: str | Path, rows: Sequence[dict[str, Any]]) -> None:
    """``OUT/fleet_summary.csv`` and ``.parquet`` of ``rows``."""
    out = Path(out)
    rows = [{c: r.get(c) for c in SUMMARY_COLUMNS} for r in rows]
    tmp = out / ".fleet_summary.csv.tmp"
    with tmp.open("w", newline="") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(SUMMARY_COLUMNS)
        writer.writerows([format_value(r[c]) for c in SUMMARY_COLUMNS] for r in rows)
    tmp.replace(out / "fleet_summary.csv")
    arrays = {c: (pa.array([None if r[c] is None else str(r[c]) for r in rows], pa.string())
                  if c in SUMMARY_TEXT_COLUMNS else
                  pa.array([_float(r[c]) for r in rows], pa.float64()))
              for c in SUMMARY_COLUMNS}
    tmp = out / ".fleet_summary.parquet.tmp"
    pq.write_table(pa.table(arrays), str(tmp))
    tmp.replace(out / "fleet_summary.parquet")


def _float(value: Any) -> float | None:
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def fleet_dataset(out: str | Path, table: str = "smoothed") -> ds.Dataset:
    """One table (``estimates``, ``smoothed`` or ``monitor``) of every drive that is ``ok``
    in OUT's ``fleet_summary.parquet`` (the last run's drives: a folder that an earlier run
    with other drives left in OUT is not served) and whose ``done.json`` is written (not a
    drive that failed or was interrupted part-way), as a pyarrow dataset with the hive
    partition column ``drive`` (text, as the drives are named). InputError where OUT holds
    no fleet summary."""
    out = Path(out)
    summary = out / "fleet_summary.parquet"
    try:
        rows = pq.read_table(summary, columns=["drive", "status"]).to_pylist()
    except FileNotFoundError:
        raise InputError(f"{out}: no fleet_summary.parquet here (not the --out of a fleet "
                         "run, or no drive of it has finished yet)") from None
    except (OSError, pa.ArrowException, KeyError) as exc:
        raise InputError(f"{summary}: not a fleet summary ({printable(exc, 200)})") from None
    folders = [drive_folder(out, r["drive"]) for r in rows
               if r["status"] == "ok" and r["drive"] is not None]
    files = sorted(str(f / f"{table}.parquet") for f in folders
                   if (f / DONE_FILE).is_file() and (f / f"{table}.parquet").is_file())
    return ds.dataset(files, format="parquet", partitioning=DRIVE_PARTITIONING,
                      partition_base_dir=str(out))


__all__ = ["CONNECT_TIMEOUT_S", "DRIVE_PARTITIONING", "SUMMARY_COLUMNS", "connect_scheduler",
           "fleet_dataset", "run_fleet", "scheduler_address", "write_summary"]
