"""Chaos run: a cluster job under random faults must give the undisturbed dataset, and nothing more.

Run: .venv/bin/python benches/chaos.py [--rounds N] [--seed S] [--workers K] [--budget-s T]
                                       [--out FILE.jsonl] [--bin-dir target/debug] [--spec TOML]
     .venv/bin/python benches/chaos.py --smoke

It owns everything it starts, all on 127.0.0.1: a throwaway Postgres cluster (initdb into a temporary
directory, fsync off), `moto_server` (S3), a fault-injecting HTTP proxy in front of moto, and per round a
`vint-coordinator` and K `vint-worker`s whose S3 endpoint is the proxy. First, once, the reference: the
embedded `vintctl run examples/tiny.toml`. Then each round, on a fresh database and bucket, submits
`examples/tiny.toml` and, at seeded random moments while the job runs, injects one fault after another,
drawn from shuffled decks of the seven kinds so every kind comes up as often as the others:

- worker_kill: SIGKILL a worker (its engines are left to notice) and start a new one;
- engine_kill: SIGKILL one engine process (`python -m vint_engines serve`) of a worker;
- coordinator_restart: SIGKILL the coordinator, start it again on the same port;
- coordinator_outage: the same, down for 2–3 leases (6–9 s): leases run out while no coordinator
  can hear their heartbeats, and reports meet the outage;
- postgres_restart_fast / postgres_restart_immediate: `pg_ctl restart -m fast|immediate`;
- postgres_outage_fast / postgres_outage_immediate: `pg_ctl stop -m fast|immediate`, then started
  again after 2–3 leases, the coordinator up all along;
- s3_window: for a few seconds the proxy answers a share of requests with 500/503 (s3_error), delays
  them (s3_slow), drops the connection before reading the body (s3_drop_request) or passes the request to
  moto and drops the connection halfway through its response (s3_drop_response).

When the job has succeeded, `vintctl export` writes its dataset, whose manifest.jsonl must equal the
reference's byte for byte, and the bucket must hold exactly the job's lineage: every object is an
artifact of one of the job's tasks or one of its submitted files, and every such object is there. Engines
left alive in a killed worker's process group at the end of the round are counted (they should exit when
their worker dies). The coordinator runs with --max-attempts 10 (the default is 4): many faults may land
on one task, and a task that fails for good is a lost sample, which fails the round.

Writes one JSON line per round to --out (faults injected by kind, failed attempts by outcome, the most
attempts one task took, wall time, identical, orphan and missing objects, stray engines) and prints the
tally; attempts that ended `lease_expired` are split into those that counted against the task's
attempts and those the coordinator did not count (`lease_expired_uncounted`: the lease ran out while
no coordinator could hear its worker). Exit status: 0 when every round ends identical with the bucket
equal to the lineage, 1 otherwise (also past --budget-s: the run fails rather than hangs), 2 for bad
arguments. Every process it started is killed at exit, also on failure and Ctrl-C. A seed fixes the
fault schedule (kinds, moments, windows), not the interleaving with the job, which the machine decides.

`--smoke` is one round of benches/smoke.toml with 2 workers and a fault every 1.5 s on average, within
a budget of 300 s, its work directory removed when the round passes: the test command's check that
the bench still runs (under a minute, not a tally). `cargo test -p vint-tests --test chaos` runs a
real round of tiny.toml.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
from packed_outputs import unpack  # noqa: E402  (the store's packed outputs, read from SQL)

SPEC = ROOT / "examples" / "tiny.toml"
SMOKE_SPEC = ROOT / "benches" / "smoke.toml"
MAX_ATTEMPTS = 10
WORKER_LEASE_MS = 3_000
FAULT_KINDS = (
    "worker_kill",
    "engine_kill",
    "coordinator_restart",
    "coordinator_outage",
    "postgres_restart",
    "postgres_outage",
    "s3_window",
)
# A long outage lasts this many worker leases, drawn uniformly.
OUTAGE_LEASES = (2.0, 3.0)
S3_FAULTS = ("s3_error", "s3_slow", "s3_drop_request", "s3_drop_response")
S3_CREDENTIALS = {
    "AWS_ALLOW_HTTP": "true",
    "AWS_ACCESS_KEY_ID": "vint-chaos",
    "AWS_SECRET_ACCESS_KEY": "vint-chaos",
    "AWS_REGION": "us-east-1",
}


class ChaosError(Exception):
    """A round or the run cannot go on: a missing tool, a process that would not start, a hung job."""


class BudgetSpent(ChaosError):
    """--budget-s has passed: the run stops."""


# --- time and processes ----------------------------------------------------------------------------


class Budget:
    """The run's hard time bound: every wait checks it, every subprocess gets what is left as timeout."""

    def __init__(self, seconds: float) -> None:
        self.deadline = time.monotonic() + seconds
        self.seconds = seconds

    def left(self) -> float:
        left = self.deadline - time.monotonic()
        if left <= 0:
            raise BudgetSpent(f"the run's budget of {self.seconds:.0f} s (--budget-s) is spent")
        return left


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for_port(port: int, what: str, seconds: float, proc: subprocess.Popen[bytes] | None = None) -> None:
    deadline = time.monotonic() + seconds
    while True:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1):
            return
        if proc is not None and proc.poll() is not None:
            raise ChaosError(f"{what} exited with status {proc.returncode} before listening on port {port}")
        if time.monotonic() > deadline:
            raise ChaosError(f"{what} did not listen on 127.0.0.1:{port} within {seconds:.0f} s")
        time.sleep(0.05)


class Processes:
    """Every process the run starts, each the leader of its own process group: killing the group at
    exit also kills what it started (a worker's engines), even after the leader died."""

    def __init__(self) -> None:
        self.groups: list[int] = []

    def start(self, argv: list[str], log: Path, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("ab") as out:
            proc = subprocess.Popen(
                argv,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env={**os.environ, **(env or {})},
                start_new_session=True,
            )
        self.groups.append(proc.pid)
        return proc

    @staticmethod
    def group_members(pgid: int) -> list[int]:
        """Live processes in process group `pgid` (Linux /proc)."""
        members = []
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            # Fields after the command name, which is in parentheses and may hold spaces.
            fields = stat[stat.rindex(")") + 2 :].split()
            if fields[0] != "Z" and int(fields[2]) == pgid:
                members.append(int(entry.name))
        return members

    def kill_group(self, pgid: int) -> None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pgid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pgid, os.WNOHANG)

    def kill_all(self) -> None:
        for pgid in reversed(self.groups):
            self.kill_group(pgid)
        self.groups.clear()


def children_of(pid: int) -> list[int]:
    out: list[int] = []
    tasks = Path(f"/proc/{pid}/task")
    if not tasks.is_dir():
        return out
    for task in tasks.iterdir():
        with contextlib.suppress(OSError):
            out.extend(int(p) for p in (task / "children").read_text().split())
    return out


def sigkill(proc: subprocess.Popen[bytes]) -> None:
    with contextlib.suppress(ProcessLookupError):
        proc.send_signal(signal.SIGKILL)
    proc.wait()


# --- Postgres: a throwaway cluster the run owns and restarts ----------------------------------------


def postgres_bin() -> Path:
    """The newest installed PostgreSQL server bin directory (holding initdb)."""
    found = sorted(
        Path("/usr/lib/postgresql").glob("*/bin/initdb"),
        key=lambda p: int(p.parts[-3]) if p.parts[-3].isdigit() else 0,
    )
    if found:
        return found[-1].parent
    initdb = shutil.which("initdb")
    if initdb:
        return Path(initdb).resolve().parent
    raise ChaosError(
        "no PostgreSQL server binaries (initdb) in /usr/lib/postgresql/*/bin or on PATH: the chaos run "
        "starts and restarts a Postgres of its own (Debian: apt-get install postgresql)"
    )


class Postgres:
    def __init__(self, bin_dir: Path, budget: Budget) -> None:
        self.bin = bin_dir
        self.budget = budget
        self.user = "postgres" if os.geteuid() == 0 else None
        # Under /tmp: the server runs as `postgres` and must reach it; the socket path stays short.
        self.dir = Path(tempfile.mkdtemp(prefix="vint-chaos-pg.", dir="/tmp"))
        if self.user:
            shutil.chown(self.dir, self.user)
        self.data = self.dir / "data"
        self.log = self.dir / "server.log"
        self.port = free_port()
        self.running = False

    def _as_owner(self, argv: list[str]) -> list[str]:
        return ["runuser", "-u", self.user, "--", *argv] if self.user else argv

    def _run(self, argv: list[str], what: str) -> None:
        done = subprocess.run(
            self._as_owner(argv), capture_output=True, text=True, timeout=min(120, self.budget.left())
        )
        if done.returncode != 0:
            tail = self.log.read_text()[-2000:] if self.log.exists() else ""
            raise ChaosError(f"{what} failed ({done.returncode}): {done.stderr.strip()}\n{tail}")

    def start(self) -> None:
        self._run(
            [
                str(self.bin / "initdb"),
                "-D",
                str(self.data),
                "-A",
                "trust",
                "-U",
                "postgres",
                "-E",
                "UTF8",
                "--locale=C",
                "--no-sync",
            ],
            "initdb",
        )
        self._run([*self._pg_ctl(), "-o", self._options(), "start"], "starting Postgres")
        self.running = True

    def _options(self) -> str:
        return (
            f"-p {self.port} -k {self.dir} -c listen_addresses=127.0.0.1 -c max_connections=100 "
            "-c fsync=off -c synchronous_commit=off -c full_page_writes=off"
        )

    def outage(self, mode: str, seconds: float) -> None:
        """`pg_ctl stop -m fast|immediate`, `seconds` down, then started again as before."""
        self._run([*self._pg_ctl(), "-m", mode, "stop"], f"pg_ctl stop -m {mode}")
        time.sleep(seconds)
        self._run([*self._pg_ctl(), "-o", self._options(), "start"], "starting Postgres again")

    def restart(self, mode: str) -> None:
        """`pg_ctl restart -m fast` (clients disconnected, checkpoint) or `-m immediate` (a crash:
        recovery from the WAL at start)."""
        self._run(
            [*self._pg_ctl(), "-m", mode, "restart"],
            f"pg_ctl restart -m {mode}",
        )

    def _pg_ctl(self) -> list[str]:
        return [str(self.bin / "pg_ctl"), "-D", str(self.data), "-l", str(self.log), "-w", "-t", "60"]

    def url(self, database: str) -> str:
        return f"postgres://postgres@127.0.0.1:{self.port}/{database}"

    def query(self, database: str, sql: str) -> list[list[str]]:
        """Rows of `sql` as text fields (psql -At); raises on any failure."""
        done = subprocess.run(
            [
                str(self.bin / "psql"),
                "-X",
                "-At",
                "-F",
                "\t",
                "-v",
                "ON_ERROR_STOP=1",
                "-d",
                self.url(database),
                "-c",
                sql,
            ],
            capture_output=True,
            text=True,
            timeout=30,
            env={**os.environ, "PGCONNECT_TIMEOUT": "5"},
        )
        if done.returncode != 0:
            raise ChaosError(f"psql on {database}: {done.stderr.strip()}")
        return [line.split("\t") for line in done.stdout.splitlines() if line]

    def stop(self) -> None:
        if self.running:
            with contextlib.suppress(Exception):
                subprocess.run(
                    self._as_owner(
                        [str(self.bin / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "stop"]
                    ),
                    capture_output=True,
                    timeout=60,
                )
            self.running = False
        shutil.rmtree(self.dir, ignore_errors=True)


def sql_text(value: str) -> str:
    return "'" + value.replace("'", "''") + "'"


# --- S3: moto behind a fault-injecting proxy ---------------------------------------------------------


@dataclass
class FaultWindow:
    kind: str
    probability: float
    until: float


class S3FaultProxy:
    """An HTTP proxy on 127.0.0.1 in front of moto. One request per connection (it answers with
    `Connection: close`); while a fault window is open, each request is hit with its probability."""

    def __init__(self, upstream_port: int, seed: int) -> None:
        self.upstream_port = upstream_port
        self.port = 0
        self.injected: Counter[str] = Counter()
        self.requests = 0
        self._rng = random.Random(seed)
        self._window: FaultWindow | None = None
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self._error: BaseException | None = None

    def start(self) -> None:
        threading.Thread(target=self._serve, name="s3-fault-proxy", daemon=True).start()
        self._ready.wait(30)
        if self._error is not None or not self.port:
            raise ChaosError(f"the S3 fault proxy did not start: {self._error}")

    def open_window(self, kind: str, probability: float, seconds: float) -> None:
        with self._lock:
            self._window = FaultWindow(kind, probability, time.monotonic() + seconds)

    def close_window(self) -> None:
        with self._lock:
            self._window = None

    def take_counts(self) -> tuple[Counter[str], int]:
        """Faults injected and requests seen since the last call."""
        with self._lock:
            counts, requests = self.injected, self.requests
            self.injected, self.requests = Counter(), 0
        return counts, requests

    def _draw(self) -> tuple[str | None, float, bool]:
        """The fault for the next request (or None), its delay if slow, and 503 rather than 500."""
        with self._lock:
            self.requests += 1
            w = self._window
            if w is None or time.monotonic() > w.until or self._rng.random() >= w.probability:
                return None, 0.0, False
            self.injected[w.kind] += 1
            return w.kind, self._rng.uniform(0.5, 4.0), self._rng.random() < 0.5

    def _serve(self) -> None:
        async def main() -> None:
            server = await asyncio.start_server(self._handle, "127.0.0.1", 0, limit=1 << 20)
            self.port = server.sockets[0].getsockname()[1]
            self._ready.set()
            async with server:
                await server.serve_forever()

        try:
            asyncio.run(main())
        except BaseException as e:
            self._error = e
            self._ready.set()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await reader.readuntil(b"\r\n\r\n")
            fault, delay, slow_down = self._draw()
            if fault == "s3_drop_request":
                writer.transport.abort()
                return
            body = await read_body(reader, head)
            if fault == "s3_error":
                status = b"503 Slow Down" if slow_down else b"500 Internal Server Error"
                code = b"SlowDown" if slow_down else b"InternalError"
                xml = b"<?xml version='1.0' encoding='UTF-8'?><Error><Code>" + code + b"</Code>"
                xml += b"<Message>injected by benches/chaos.py</Message></Error>"
                writer.write(b"HTTP/1.1 " + status + b"\r\nContent-Type: application/xml\r\n")
                writer.write(b"Content-Length: %d\r\nConnection: close\r\n\r\n" % len(xml) + xml)
                await writer.drain()
                return
            response = await asyncio.wait_for(self._forward(head, body), 120)
            if fault == "s3_slow":
                await asyncio.sleep(delay)
            if fault == "s3_drop_response":
                # Halfway through the body, or through the head when there is no body (a PUT's).
                head_end = response.find(b"\r\n\r\n") + 4
                cut = (head_end + len(response)) // 2 if len(response) > head_end else head_end // 2
                writer.write(response[:cut])
                await writer.drain()
                writer.transport.abort()
                return
            writer.write(response)
            await writer.drain()
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError):
            writer.transport.abort()
        finally:
            writer.close()

    async def _forward(self, head: bytes, body: bytes) -> bytes:
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream_port)
        try:
            up_writer.write(with_connection_close(head) + body)
            await up_writer.drain()
            response = await up_reader.read()
        finally:
            up_writer.close()
        split = response.find(b"\r\n\r\n")
        if split < 0:
            raise OSError("moto sent no complete response head")
        return with_connection_close(response[: split + 4]) + response[split + 4 :]


def with_connection_close(head: bytes) -> bytes:
    """An HTTP message head with its Connection/Keep-Alive headers replaced by `Connection: close`."""
    lines = head[:-4].split(b"\r\n")
    kept = [lines[0]] + [
        line
        for line in lines[1:]
        if line.split(b":", 1)[0].strip().lower() not in (b"connection", b"keep-alive")
    ]
    return b"\r\n".join([*kept, b"Connection: close"]) + b"\r\n\r\n"


async def read_body(reader: asyncio.StreamReader, head: bytes) -> bytes:
    """The raw request body after `head`: Content-Length bytes, or a chunked body up to its end."""
    headers = {}
    for line in head[:-4].split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        headers[name.strip().lower()] = value.strip()
    if b"chunked" in headers.get(b"transfer-encoding", b"").lower():
        raw = b""
        while True:
            size_line = await reader.readuntil(b"\r\n")
            raw += size_line
            size = int(size_line.split(b";")[0].strip(), 16)
            if size == 0:
                while True:  # trailers, then the empty line
                    trailer = await reader.readuntil(b"\r\n")
                    raw += trailer
                    if trailer == b"\r\n":
                        return raw
            raw += await reader.readexactly(size + 2)
    length = int(headers.get(b"content-length", b"0") or b"0")
    return await reader.readexactly(length) if length else b""


class S3:
    """moto_server on a free port, with the boto3 client the run uses to make and list buckets."""

    def __init__(self, processes: Processes, logs: Path) -> None:
        moto = Path(sys.executable).with_name("moto_server")
        if not moto.exists():
            raise ChaosError(f"{moto} is missing: run scripts/setup-python.sh --dev (the dev tools)")
        self.port = free_port()
        proc = processes.start([str(moto), "-H", "127.0.0.1", "-p", str(self.port)], logs / "moto.log")
        wait_for_port(self.port, "moto_server", 60, proc)
        import boto3  # the venv's, installed with moto

        self.client: Any = boto3.client("s3", endpoint_url=self.endpoint(), **boto3_credentials())

    def endpoint(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def make_bucket(self, bucket: str) -> None:
        self.client.create_bucket(Bucket=bucket)

    def keys(self, bucket: str) -> set[str]:
        keys: set[str] = set()
        for page in self.client.get_paginator("list_objects_v2").paginate(Bucket=bucket):
            keys.update(o["Key"] for o in page.get("Contents", []))
        return keys


def boto3_credentials() -> dict[str, str]:
    return {
        "aws_access_key_id": S3_CREDENTIALS["AWS_ACCESS_KEY_ID"],
        "aws_secret_access_key": S3_CREDENTIALS["AWS_SECRET_ACCESS_KEY"],
        "region_name": S3_CREDENTIALS["AWS_REGION"],
    }


def s3_env(endpoint: str) -> dict[str, str]:
    return {**S3_CREDENTIALS, "AWS_ENDPOINT_URL": endpoint}


# --- one round --------------------------------------------------------------------------------------


@dataclass
class Run:
    """What every round shares."""

    args: argparse.Namespace
    budget: Budget
    processes: Processes
    postgres: Postgres
    s3: S3
    proxy: S3FaultProxy
    reference_manifest: bytes
    work: Path

    def binary(self, name: str) -> str:
        return str(Path(self.args.bin_dir) / name)


@dataclass
class Worker:
    name: str
    proc: subprocess.Popen[bytes]


@dataclass
class Round:
    """One round's cluster: a coordinator and workers on its own database and bucket."""

    run: Run
    number: int
    rng: random.Random
    dir: Path
    database: str
    bucket: str
    coordinator_port: int = field(default_factory=free_port)
    coordinator: subprocess.Popen[bytes] | None = None
    workers: list[Worker] = field(default_factory=list)
    incarnations: Counter[str] = field(default_factory=Counter)
    killed_groups: list[int] = field(default_factory=list)
    faults: Counter[str] = field(default_factory=Counter)
    log: list[str] = field(default_factory=list)
    started: float = field(default_factory=time.monotonic)

    @property
    def coordinator_url(self) -> str:
        return f"http://127.0.0.1:{self.coordinator_port}"

    @property
    def store(self) -> str:
        return f"s3://{self.bucket}"

    def note(self, what: str) -> None:
        line = f"[round {self.number} +{time.monotonic() - self.started:6.1f}s] {what}"
        self.log.append(line)
        print(line, file=sys.stderr, flush=True)

    def start_coordinator(self) -> None:
        self.incarnations["coordinator"] += 1
        proc = self.run.processes.start(
            [
                self.run.binary("vint-coordinator"),
                "--database",
                self.run.postgres.url(self.database),
                "--listen",
                f"127.0.0.1:{self.coordinator_port}",
                "--store",
                self.store,
                "--max-attempts",
                str(MAX_ATTEMPTS),
                "--backoff-ms",
                "200",
            ],
            self.dir / "logs" / f"coordinator-{self.incarnations['coordinator']}.log",
            s3_env(f"http://127.0.0.1:{self.run.proxy.port}"),
        )
        wait_for_port(self.coordinator_port, "vint-coordinator", 60, proc)
        self.coordinator = proc

    def start_worker(self, slot: int) -> Worker:
        base = f"w{slot}"
        self.incarnations[base] += 1
        name = f"{base}-{self.incarnations[base]}"
        proc = self.run.processes.start(
            [
                self.run.binary("vint-worker"),
                "--coordinator",
                self.coordinator_url,
                "--store",
                self.store,
                "--worker-id",
                name,
                "--lease-ms",
                str(WORKER_LEASE_MS),
                "--python",
                self.run.args.python,
                "--scratch",
                str(self.dir / "scratch" / name),
            ],
            self.dir / "logs" / f"{name}.log",
            s3_env(f"http://127.0.0.1:{self.run.proxy.port}"),
        )
        return Worker(name, proc)

    def vintctl(
        self, args: list[str], timeout: float, direct_s3: bool = False
    ) -> subprocess.CompletedProcess[str]:
        env = {**os.environ, "VINT_PYTHON": self.run.args.python}
        if direct_s3:
            env.update(s3_env(self.run.s3.endpoint()))
        return subprocess.run(
            [self.run.binary("vintctl"), "--coordinator", self.coordinator_url, *args],
            capture_output=True,
            text=True,
            timeout=min(timeout, self.run.budget.left()),
            env=env,
        )

    def job_state(self, job: str) -> str | None:
        """The job's state straight from Postgres; None while the database is unreachable."""
        try:
            rows = self.run.postgres.query(
                self.database, f"SELECT state FROM jobs WHERE id = {sql_text(job)}"
            )
        except (ChaosError, subprocess.TimeoutExpired):
            return None
        return rows[0][0] if rows else None

    # --- faults ---

    def inject(self, kind: str) -> None:
        match kind:
            case "worker_kill":
                slot = self.rng.randrange(len(self.workers))
                victim = self.workers[slot]
                sigkill(victim.proc)
                self.killed_groups.append(victim.proc.pid)
                self.faults[kind] += 1
                time.sleep(self.rng.uniform(0.0, 2.0))
                self.workers[slot] = self.start_worker(slot + 1)
                self.note(f"SIGKILLed worker {victim.name}; started {self.workers[slot].name}")
            case "engine_kill":
                self.kill_an_engine()
            case "coordinator_restart":
                if self.coordinator is not None:
                    sigkill(self.coordinator)
                down = self.rng.uniform(0.2, 3.0)
                time.sleep(down)
                self.start_coordinator()
                self.faults[kind] += 1
                self.note(f"SIGKILLed the coordinator; restarted it after {down:.1f} s")
            case "coordinator_outage":
                if self.coordinator is not None:
                    sigkill(self.coordinator)
                down = self.rng.uniform(*OUTAGE_LEASES) * WORKER_LEASE_MS / 1000
                time.sleep(down)
                self.start_coordinator()
                self.faults[kind] += 1
                self.note(f"SIGKILLed the coordinator; restarted it after {down:.1f} s (longer than a lease)")
            case "postgres_outage":
                mode = self.rng.choice(["fast", "immediate"])
                down = self.rng.uniform(*OUTAGE_LEASES) * WORKER_LEASE_MS / 1000
                self.run.postgres.outage(mode, down)
                self.faults[f"postgres_outage_{mode}"] += 1
                self.note(f"stopped Postgres -m {mode}; started it again after {down:.1f} s")
            case "postgres_restart":
                mode = self.rng.choice(["fast", "immediate"])
                started = time.monotonic()
                self.run.postgres.restart(mode)
                self.faults[f"postgres_restart_{mode}"] += 1
                self.note(f"restarted Postgres -m {mode} ({time.monotonic() - started:.1f} s)")
            case "s3_window":
                fault = self.rng.choice(S3_FAULTS)
                probability = self.rng.uniform(0.2, 0.6)
                seconds = self.rng.uniform(3.0, 10.0)
                self.run.proxy.open_window(fault, probability, seconds)
                self.faults[kind] += 1
                self.note(f"S3 fault window: {fault}, p={probability:.2f}, {seconds:.1f} s")
            case _:
                raise ValueError(kind)

    def kill_an_engine(self) -> None:
        """SIGKILLs one engine of a random worker that has one; waits up to 3 s for one to exist."""
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            candidates = [(w, pid) for w in self.workers for pid in children_of(w.proc.pid)]
            if candidates:
                worker, pid = self.rng.choice(candidates)
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
                    self.faults["engine_kill"] += 1
                    self.note(f"SIGKILLed engine {pid} of {worker.name}")
                return
            time.sleep(0.1)
        self.note("no engine to kill")

    # --- the round ---

    def play(self) -> dict[str, Any]:
        self.started = time.monotonic()
        args = self.run.args
        self.run.postgres.query("postgres", f"CREATE DATABASE {self.database}")
        self.run.s3.make_bucket(self.bucket)
        self.run.proxy.close_window()
        self.run.proxy.take_counts()
        self.start_coordinator()
        submitted = self.vintctl(["submit", str(args.spec)], 120)
        if submitted.returncode != 0:
            raise ChaosError(f"vintctl submit: {submitted.stderr.strip()}")
        job = submitted.stdout.strip()
        self.workers = [self.start_worker(slot) for slot in range(1, args.workers + 1)]
        self.note(f"job {job}: {args.workers} workers")

        deck: list[str] = []
        state = self.job_state(job)
        round_deadline = time.monotonic() + args.round_timeout_s
        while state not in ("succeeded", "failed", "cancelled"):
            gap = self.rng.uniform(0.5 * args.gap_s, 1.5 * args.gap_s)
            until = time.monotonic() + gap
            while time.monotonic() < until and state not in ("succeeded", "failed", "cancelled"):
                self.run.budget.left()
                if time.monotonic() > round_deadline:
                    raise ChaosError(f"job {job} did not end within {args.round_timeout_s:.0f} s")
                time.sleep(0.5)
                state = self.job_state(job)
            if state in ("succeeded", "failed", "cancelled"):
                break
            if not deck:
                deck = list(FAULT_KINDS)
                self.rng.shuffle(deck)
            self.inject(deck.pop())
            state = self.job_state(job)
        self.run.proxy.close_window()
        job_s = time.monotonic() - self.started
        self.note(f"job {state} after {job_s:.1f} s")

        result: dict[str, Any] = {"round": self.number, "job": job, "job_state": state}
        s3_counts, s3_requests = self.run.proxy.take_counts()
        self.faults.update(s3_counts)
        result["faults"] = dict(sorted(self.faults.items()))
        result["s3_requests"] = s3_requests
        result["failed_attempts"] = self.failed_attempts(job)
        result["most_attempts"] = self.most_attempts(job)
        if state != "succeeded":
            result["error"] = f"job {state}: " + "; ".join(self.failed_tasks(job))
            return result | self.stray_engines()

        dataset = self.dir / "dataset"
        exported = self.vintctl(["export", job, "--out", str(dataset), "--store", self.store], 300, True)
        if exported.returncode != 0:
            result["error"] = f"vintctl export: {exported.stderr.strip()}"
            return result | self.stray_engines()
        manifest = (dataset / "manifest.jsonl").read_bytes()
        result["identical"] = manifest == self.run.reference_manifest
        result["samples"] = sum(1 for line in manifest.splitlines() if b'"sample_id"' in line)
        if not result["identical"]:
            (self.dir / "reference-manifest.jsonl").write_bytes(self.run.reference_manifest)
            ours, theirs = set(manifest.splitlines()), set(self.run.reference_manifest.splitlines())
            result["differing_lines"] = len(ours ^ theirs)
        result |= self.bucket_against_lineage(job)
        return result | self.stray_engines()

    def failed_attempts(self, job: str) -> dict[str, int]:
        """Attempts that did not succeed, by outcome (retry, lease_expired, lease_expired_uncounted,
        failed, released)."""
        rows = self.run.postgres.query(
            self.database,
            "SELECT CASE WHEN a.outcome = 'lease_expired' AND a.error LIKE '%not counted%' "
            "THEN 'lease_expired_uncounted' ELSE a.outcome END AS o, count(*) "
            "FROM attempts a JOIN tasks t ON t.id = a.task_id "
            f"WHERE t.job_id = {sql_text(job)} AND a.outcome <> 'succeeded' GROUP BY o ORDER BY 1",
        )
        return {outcome: int(n) for outcome, n in rows}

    def most_attempts(self, job: str) -> int:
        """The most attempts any task of the job took (the coordinator allows MAX_ATTEMPTS)."""
        rows = self.run.postgres.query(
            self.database, f"SELECT coalesce(max(attempt), 0) FROM tasks WHERE job_id = {sql_text(job)}"
        )
        return int(rows[0][0])

    def failed_tasks(self, job: str) -> list[str]:
        rows = self.run.postgres.query(
            self.database,
            f"SELECT key, coalesce(last_error, '') FROM tasks WHERE job_id = {sql_text(job)} "
            "AND state <> 'succeeded' ORDER BY key LIMIT 10",
        )
        return [f"{key}: {error}" for key, error in rows]

    def bucket_against_lineage(self, job: str) -> dict[str, Any]:
        """Objects in the bucket outside the job's lineage (orphans), and lineage objects missing."""
        outputs = self.run.postgres.query(
            self.database,
            "SELECT encode(o.files, 'hex') FROM outputs o JOIN tasks t ON t.id = o.task_id "
            f"WHERE t.job_id = {sql_text(job)}",
        )
        assets = self.run.postgres.query(
            self.database, f"SELECT object_key FROM job_assets WHERE job_id = {sql_text(job)}"
        )
        lineage = {f.object_key for row in outputs for f in unpack(bytes.fromhex(row[0]))}
        lineage |= {row[0] for row in assets}
        stored = self.run.s3.keys(self.bucket)
        orphans, missing = sorted(stored - lineage), sorted(lineage - stored)
        if orphans or missing:
            (self.dir / "bucket-vs-lineage.json").write_text(
                json.dumps({"orphans": orphans, "missing": missing}, indent=1)
            )
        return {"objects": len(stored), "orphan_objects": len(orphans), "missing_objects": len(missing)}

    def stray_engines(self) -> dict[str, int]:
        """Processes still alive in the groups of workers this round SIGKILLed: engines that did not
        exit when their worker died. Given a few seconds, then killed."""
        deadline = time.monotonic() + 5.0
        stray = [pid for g in self.killed_groups for pid in Processes.group_members(g)]
        while stray and time.monotonic() < deadline:
            time.sleep(0.2)
            stray = [pid for g in self.killed_groups for pid in Processes.group_members(g)]
        for group in self.killed_groups:
            self.run.processes.kill_group(group)
        return {"stray_engines": len(stray)}

    def stop(self) -> None:
        for w in self.workers:
            self.run.processes.kill_group(w.proc.pid)
        if self.coordinator is not None:
            self.run.processes.kill_group(self.coordinator.pid)


# --- the run ----------------------------------------------------------------------------------------


def reference_manifest(run_args: argparse.Namespace, work: Path, budget: Budget) -> bytes:
    """manifest.jsonl of the embedded `vintctl run` of the spec: what every round must equal."""
    out = work / "reference"
    started = time.monotonic()
    done = subprocess.run(
        [
            str(Path(run_args.bin_dir) / "vintctl"),
            "run",
            str(run_args.spec),
            "--out",
            str(out / "out"),
            "--state",
            str(out / "state"),
            "--workers",
            "2",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=budget.left(),
        env={**os.environ, "VINT_PYTHON": run_args.python},
    )
    if done.returncode != 0:
        raise ChaosError(
            f"the reference run (vintctl run {run_args.spec}) failed: {done.stderr.strip()[-2000:]}"
        )
    manifest = (out / "out" / "manifest.jsonl").read_bytes()
    print(
        f"reference: embedded run in {time.monotonic() - started:.1f} s, "
        f"{sum(1 for line in manifest.splitlines() if b'sample_id' in line)} samples",
        file=sys.stderr,
        flush=True,
    )
    return manifest


def passed(result: dict[str, Any]) -> bool:
    return (
        result.get("identical") is True
        and result.get("orphan_objects") == 0
        and result.get("missing_objects") == 0
        and "error" not in result
    )


def tally(results: list[dict[str, Any]]) -> str:
    faults: Counter[str] = Counter()
    attempts: Counter[str] = Counter()
    for r in results:
        faults.update(r.get("faults", {}))
        attempts.update(r.get("failed_attempts", {}))
    walls = [r["wall_s"] for r in results if "wall_s" in r]
    lines = [
        f"rounds: {len(results)}, identical manifests: {sum(1 for r in results if r.get('identical'))}"
        f"/{len(results)}, passed: {sum(1 for r in results if passed(r))}/{len(results)}",
        "faults: " + ", ".join(f"{k} {v}" for k, v in sorted(faults.items())),
        "failed attempts: "
        + (", ".join(f"{k} {v}" for k, v in sorted(attempts.items())) or "none")
        + f"; most attempts of one task: {max((r.get('most_attempts', 0) for r in results), default=0)}",
        f"orphan objects: {sum(r.get('orphan_objects', 0) for r in results)}, missing objects: "
        f"{sum(r.get('missing_objects', 0) for r in results)}, stray engines: "
        f"{sum(r.get('stray_engines', 0) for r in results)}",
    ]
    if walls:
        lines.append(
            f"wall per round: median {statistics.median(walls):.1f} s (min {min(walls)}, max {max(walls)})"
        )
    return "\n".join(lines)


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    p.add_argument("--rounds", type=int, default=1, help="rounds of chaos (default 1)")
    p.add_argument("--seed", type=int, default=1, help="seed of the fault schedule (default 1)")
    p.add_argument("--workers", type=int, default=3, help="workers per round (default 3)")
    p.add_argument("--budget-s", type=float, default=3600, help="hard bound on the whole run (default 3600)")
    p.add_argument("--round-timeout-s", type=float, default=900, help="longest a round's job may run")
    p.add_argument("--gap-s", type=float, default=5.0, help="mean seconds between faults (default 5)")
    p.add_argument("--out", type=Path, help="one JSON line per round (default: WORK_DIR/chaos.jsonl)")
    p.add_argument("--bin-dir", type=Path, default=ROOT / "target" / "debug", help="vint binaries")
    p.add_argument("--python", default=sys.executable, help="the engines' Python (default: this one)")
    p.add_argument("--spec", type=Path, default=SPEC, help="the job's spec (default examples/tiny.toml)")
    p.add_argument(
        "--smoke",
        action="store_true",
        help="1 round of benches/smoke.toml, 2 workers, gap 1.5 s, budget 300 s (under a minute)",
    )
    p.add_argument(
        "--work-dir",
        type=Path,
        help="logs, and failed rounds' datasets (default: a temporary directory, kept)",
    )
    args = p.parse_args(argv)
    if args.smoke:
        args.rounds, args.workers, args.gap_s, args.spec = 1, 2, 1.5, SMOKE_SPEC
        args.budget_s, args.round_timeout_s = 300.0, 120.0
    for name, low in (("rounds", 1), ("workers", 1)):
        if getattr(args, name) < low:
            p.error(f"--{name.replace('_', '-')} {getattr(args, name)}: must be at least {low}")
    for name in ("budget_s", "round_timeout_s", "gap_s"):
        if not getattr(args, name) > 0:
            p.error(f"--{name.replace('_', '-')} {getattr(args, name)}: must be positive")
    for binary in ("vint-coordinator", "vint-worker", "vintctl"):
        if not (args.bin_dir / binary).exists():
            p.error(f"--bin-dir {args.bin_dir}: no {binary} there (cargo build --workspace --bins)")
    return args


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    args.bin_dir = args.bin_dir.resolve()
    work = args.work_dir or Path(tempfile.mkdtemp(prefix="vint-chaos."))
    work.mkdir(parents=True, exist_ok=True)
    out_path: Path = args.out or work / "chaos.jsonl"
    out_path.parent.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    print(f"chaos: work directory {work}, tally {out_path}", file=sys.stderr, flush=True)
    status = play_rounds(args, work, out_path)
    if status == 0 and args.smoke and args.work_dir is None:
        shutil.rmtree(work, ignore_errors=True)
    return status


def play_rounds(args: argparse.Namespace, work: Path, out_path: Path) -> int:
    """Every round, on a Postgres, moto and proxy of the run's own; 0 when every round passed."""
    budget = Budget(args.budget_s)
    processes = Processes()
    postgres: Postgres | None = None
    results: list[dict[str, Any]] = []
    try:
        postgres = Postgres(postgres_bin(), budget)
        postgres.start()
        s3 = S3(processes, work / "logs")
        proxy = S3FaultProxy(s3.port, args.seed)
        proxy.start()
        reference = reference_manifest(args, work, budget)
        run = Run(args, budget, processes, postgres, s3, proxy, reference, work)
        with out_path.open("w") as out:
            for number in range(1, args.rounds + 1):
                results.append(play_round(run, number, out))
    except (ChaosError, subprocess.TimeoutExpired) as e:
        print(f"chaos: ERROR: {e}", file=sys.stderr)
        return 1
    finally:
        processes.kill_all()
        if postgres is not None:
            postgres.stop()
        if results:
            print(tally(results), file=sys.stderr)
    return 0 if all(passed(r) for r in results) else 1


def play_round(run: Run, number: int, out: IO[str]) -> dict[str, Any]:
    rng = random.Random(f"{run.args.seed}:{number}")
    directory = run.work / f"round-{number:02d}"
    r = Round(run, number, rng, directory, f"chaos_r{number}", f"chaos-r{number}")
    spent: BudgetSpent | None = None
    try:
        result = r.play()
    except (ChaosError, subprocess.TimeoutExpired) as e:
        result = {"error": str(e), "faults": dict(sorted(r.faults.items()))}
        if isinstance(e, BudgetSpent) or run.budget.deadline < time.monotonic():
            spent = BudgetSpent(f"the run's budget of {run.budget.seconds:.0f} s (--budget-s) is spent")
    finally:
        r.stop()
        # Twenty rounds of datasets and killed workers' scratch would fill a small disk; logs stay.
        shutil.rmtree(directory / "scratch", ignore_errors=True)
    wall_s = round(time.monotonic() - r.started, 1)
    result = {"round": number, "seed": run.args.seed, **result, "wall_s": wall_s, "passed": passed(result)}
    if result["passed"]:
        shutil.rmtree(directory / "dataset", ignore_errors=True)
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "faults.log").write_text("\n".join(r.log) + "\n")
    out.write(json.dumps(result) + "\n")
    out.flush()
    print(f"round {number}: {json.dumps(result)}", file=sys.stderr, flush=True)
    if spent is not None:
        raise spent
    return result


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
