"""Throwaway PostgreSQL and Redis servers for the distributed tests.

Each test session starts its own instances from Debian's binaries (``postgresql``,
``redis-server``) on 127.0.0.1 and a free port, in a temporary directory: the tests stop,
kill and restart them at will without touching any server the machine already runs. When a
binary is missing or a server cannot start, ``Unavailable`` says why and the tests skip.
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from tests.service.live import free_port


class Unavailable(RuntimeError):
    """The server cannot run on this machine (the message says why)."""


def _postgres_bin(name: str) -> str:
    found = shutil.which(name)
    if found:
        return found
    # Debian keeps the server binaries out of PATH, one folder per major version.
    candidates = sorted(
        glob.glob(f"/usr/lib/postgresql/*/bin/{name}"),
        key=lambda p: int(Path(p).parts[-3]) if Path(p).parts[-3].isdigit() else 0,
    )
    if not candidates:
        raise Unavailable(
            f"PostgreSQL's {name} not found (apt-get install postgresql; .ci/run does this)"
        )
    return candidates[-1]


class PostgresServer:
    """A private PostgreSQL cluster: trust auth for user ``sparsesplat``, no fsync."""

    def __init__(self) -> None:
        self.initdb = _postgres_bin("initdb")
        self.pg_ctl = _postgres_bin("pg_ctl")
        self.prefix: list[str] = []
        if os.geteuid() == 0:  # PostgreSQL refuses to run as root: run it as 'postgres'
            try:
                import pwd

                pwd.getpwnam("postgres")
            except KeyError as exc:
                raise Unavailable("running as root and there is no 'postgres' user") from exc
            self.prefix = ["runuser", "-u", "postgres", "--"]
        self.root = Path(tempfile.mkdtemp(prefix="sparsesplat-pg-"))
        self.data = self.root / "data"
        self.logfile = self.root / "postgres.log"
        if self.prefix:
            shutil.chown(self.root, "postgres", "postgres")
        self.port = free_port()
        try:
            self._initdb()
        except BaseException:
            shutil.rmtree(self.root, ignore_errors=True)
            raise

    def _initdb(self) -> None:
        self._run([self.initdb, "-D", str(self.data), "-U", "sparsesplat", "--auth=trust",
                   "-E", "UTF8", "--no-sync", "--no-instructions"], timeout=120)  # fmt: skip

    def _run(self, argv: list[str], timeout: float = 60) -> None:
        result = subprocess.run(
            self.prefix + argv, capture_output=True, text=True, timeout=timeout, cwd=self.root
        )
        if result.returncode != 0:
            raise Unavailable(
                f"{Path(argv[0]).name} failed: {(result.stderr or result.stdout)[-800:]}"
            )

    def start(self) -> None:
        """Start (or restart after ``stop``) on the same port and data."""
        options = (
            f"-h 127.0.0.1 -p {self.port} -k {self.root} -c fsync=off "
            "-c synchronous_commit=off -c full_page_writes=off -c max_connections=200"
        )
        self._run([self.pg_ctl, "-D", str(self.data), "-l", str(self.logfile), "-o", options,
                   "-w", "-t", "60", "start"], timeout=90)  # fmt: skip

    def stop(self, mode: str = "fast") -> None:
        """Stop: ``fast`` ends every session (what a restart by an operator does)."""
        self._run([self.pg_ctl, "-D", str(self.data), "-m", mode, "-w", "-t", "60", "stop"],
                  timeout=90)  # fmt: skip

    def url(self, database: str = "postgres") -> str:
        """``postgresql://`` URL of ``database``."""
        return f"postgresql://sparsesplat@127.0.0.1:{self.port}/{database}"

    def create_database(self, name: str) -> str:
        """A new empty database; returns its URL."""
        import psycopg

        with psycopg.connect(self.url(), autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def close(self) -> None:
        """Stop and remove everything."""
        with contextlib.suppress(Exception):
            self.stop("immediate")
        shutil.rmtree(self.root, ignore_errors=True)


class RedisServer:
    """A private redis-server without persistence: a restart loses every message."""

    def __init__(self) -> None:
        self.binary = shutil.which("redis-server")
        if self.binary is None:
            raise Unavailable(
                "redis-server not found (apt-get install redis-server; .ci/run does this)"
            )
        self.root = Path(tempfile.mkdtemp(prefix="sparsesplat-redis-"))
        self.port = free_port()
        self.process: subprocess.Popen[bytes] | None = None
        self._databases = iter(range(1, 16))

    def start(self) -> None:
        """Start (or start again, empty) on the same port."""
        log = (self.root / "redis.log").open("ab")
        self.process = subprocess.Popen(
            [self.binary, "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no", "--dir", str(self.root), "--protected-mode", "no"],
            stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        import redis

        client = redis.Redis(host="127.0.0.1", port=self.port, socket_connect_timeout=1)
        deadline = time.monotonic() + 30
        while True:
            try:
                client.ping()
                return
            except redis.RedisError:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    raise Unavailable(f"redis-server did not start: {self.tail()}") from None
                time.sleep(0.05)
            finally:
                client.close()

    def kill(self) -> None:
        """SIGKILL: what a crash or an out-of-memory kill does (nothing is saved)."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait()

    def url(self, database: int | None = None) -> str:
        """Broker URL; each call without ``database`` gives a fresh database number."""
        number = next(self._databases) if database is None else database
        return f"redis://127.0.0.1:{self.port}/{number}"

    def tail(self) -> str:
        """The end of the server's log."""
        path = self.root / "redis.log"
        return path.read_text(errors="replace")[-1500:] if path.exists() else ""

    def close(self) -> None:
        """Kill and remove everything."""
        self.kill()
        shutil.rmtree(self.root, ignore_errors=True)
