"""A real S3-protocol server for tests: moto's standalone server (``moto[server]``, installed
by name) as a subprocess on loopback, enforcing credentials.

moto checks signatures against its own IAM once ``INITIAL_NO_AUTH_ACTION_COUNT`` requests
have been served without: the first three create a user, its access key and a policy that
allows everything; from then on every request must be signed with that key, so a wrong
secret or an unknown key is refused as a real store refuses it (``SignatureDoesNotMatch``,
``InvalidAccessKeyId``).
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.service.live import free_port

SETUP_REQUESTS = 3
"""Requests served without credentials: create the user, its key, its policy."""
REGION = "us-east-1"


class MotoS3:
    """moto's server, one IAM user with full access, and buckets made on demand."""

    def __init__(self, log: Path) -> None:
        self.port = free_port()
        self.endpoint = f"http://127.0.0.1:{self.port}"
        self.log = log
        self.proc: subprocess.Popen[bytes] | None = None
        self.access_key = ""
        self.secret_key = ""

    def start(self, timeout: float = 60) -> None:
        """Start the server and create the user (the only unsigned requests)."""
        env = {**os.environ, "INITIAL_NO_AUTH_ACTION_COUNT": str(SETUP_REQUESTS)}
        for name in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN"):
            env.pop(name, None)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(self.port)],
            env=env, stdout=self.log.open("ab"), stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        deadline = time.monotonic() + timeout
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"moto server exited: {self.log.read_text()[-2000:]}")
            try:  # the dashboard's API answers without counting as an AWS request
                httpx.get(f"{self.endpoint}/moto-api/data.json", timeout=1)
                break
            except httpx.TransportError:
                if time.monotonic() > deadline:
                    raise TimeoutError("moto server did not start") from None
                time.sleep(0.1)
        iam = self.client("iam", "setup", "setup")
        iam.create_user(UserName="sparsesplat")
        key = iam.create_access_key(UserName="sparsesplat")["AccessKey"]
        policy = {"Version": "2012-10-17",
                  "Statement": [{"Effect": "Allow", "Action": "*", "Resource": "*"}]}  # fmt: skip
        iam.put_user_policy(
            UserName="sparsesplat", PolicyName="all", PolicyDocument=json.dumps(policy)
        )
        self.access_key, self.secret_key = key["AccessKeyId"], key["SecretAccessKey"]

    def client(self, service: str = "s3", access: str | None = None,
               secret: str | None = None) -> Any:  # fmt: skip
        """A boto3 client of this server (the user's key unless others are given)."""
        import boto3

        return boto3.client(
            service, endpoint_url=self.endpoint, region_name=REGION,
            aws_access_key_id=access or self.access_key,
            aws_secret_access_key=secret or self.secret_key,
        )  # fmt: skip

    def new_bucket(self) -> str:
        """A fresh, empty bucket."""
        name = f"t-{uuid.uuid4().hex[:12]}"
        self.client().create_bucket(Bucket=name)
        return name

    def objects(self, bucket: str, prefix: str = "") -> dict[str, int]:
        """Key → size of the objects under ``prefix``."""
        pages = (
            self.client().get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix)
        )
        return {o["Key"]: o["Size"] for page in pages for o in page.get("Contents", [])}

    def settings_env(self, bucket: str, prefix: str = "deploy") -> dict[str, str]:
        """The ``SPARSESPLAT_*`` variables a service on this bucket is given."""
        return {
            "SPARSESPLAT_ARTIFACTS": f"s3://{bucket}/{prefix}",
            "SPARSESPLAT_S3_ENDPOINT_URL": self.endpoint,
            "SPARSESPLAT_S3_REGION": REGION,
            "SPARSESPLAT_S3_ACCESS_KEY_ID": self.access_key,
            "SPARSESPLAT_S3_SECRET_ACCESS_KEY": self.secret_key,
        }

    def stop(self) -> None:
        """End the server."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(timeout=10)
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()


def start_moto(log: Path) -> MotoS3:
    """A started :class:`MotoS3`; raises ImportError when moto or boto3 is missing."""
    import boto3  # noqa: F401
    import moto.server  # noqa: F401

    server = MotoS3(log)
    try:
        server.start()
    except BaseException:
        server.stop()
        raise
    return server


def moto_fixture(tmp_path_factory: pytest.TempPathFactory) -> Iterator[MotoS3]:
    """moto's S3 server for the session (skips when moto[server] / boto3 are missing); a
    conftest makes it a fixture: ``s3 = pytest.fixture(scope="session")(moto_fixture)``."""
    try:
        server = start_moto(tmp_path_factory.mktemp("moto") / "moto.log")
    except ImportError as exc:
        pytest.skip(f"{exc.name} missing: pip install 'moto[server]' boto3 (the dev extra)")
    yield server
    server.stop()
