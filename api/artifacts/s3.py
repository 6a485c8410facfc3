"""The artifact store on any S3-API object store (AWS S3, MinIO, Ceph, R2, ...), via boto3.

boto3 is the ``s3`` extra (``pip install 'sparsesplat[s3]'``): it is imported only when an
``s3://`` location is configured, so light installs never need it.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sparsesplat.api.artifacts.errors import ArtifactMissing, ArtifactRefused, ArtifactStoreError
from sparsesplat.api.disk import PARTIAL_SUFFIX

REFUSED_CODES = frozenset({
    "InvalidAccessKeyId", "SignatureDoesNotMatch", "AccessDenied", "ExpiredToken",
    "InvalidToken", "InvalidClientTokenId", "UnrecognizedClientException", "403",
})  # fmt: skip
"""S3 error codes that mean the credentials were refused."""
MISSING_CODES = frozenset({"NoSuchKey", "NotFound", "404"})
"""S3 error codes that mean the object is not there."""
MULTIPART_THRESHOLD = 8 * 2**20
"""Files above this go up in parts (8 MiB, boto3's default), each part retried by itself."""


def parse_s3_url(url: str) -> tuple[str, str]:
    """``s3://bucket/some/prefix`` → (``bucket``, ``some/prefix``); ValueError otherwise."""
    if not url.startswith("s3://"):
        raise ValueError(f"not an s3:// location: {url!r}")
    bucket, _, prefix = url[len("s3://") :].partition("/")
    if not bucket:
        raise ValueError(f"no bucket in {url!r}: write s3://BUCKET or s3://BUCKET/PREFIX")
    return bucket, prefix.strip("/")


class S3Artifacts:
    """Objects under ``prefix`` in one bucket of an S3-API endpoint."""

    def __init__(
        self,
        url: str,
        endpoint_url: str | None = None,
        region: str | None = None,
        access_key_id: str | None = None,
        secret_access_key: str | None = None,
    ) -> None:
        """The store at ``url`` (``s3://bucket/prefix``). Credentials not given here come
        from boto3's usual chain (``AWS_ACCESS_KEY_ID`` / ``AWS_SECRET_ACCESS_KEY``, a
        profile, an instance role)."""
        try:
            import boto3
            from boto3.s3.transfer import TransferConfig
            from botocore.config import Config
        except ImportError as exc:
            raise ArtifactStoreError(f"{url} needs boto3: pip install 'sparsesplat[s3]'") from exc
        self.bucket, self.prefix = parse_s3_url(url)
        self.endpoint_url = endpoint_url
        session = boto3.session.Session(
            aws_access_key_id=access_key_id,
            aws_secret_access_key=secret_access_key,
            region_name=region or os.environ.get("AWS_DEFAULT_REGION") or "us-east-1",
        )
        # Path-style addressing: what MinIO and most S3-compatible stores expect, and what
        # works with any bucket name. Few, quick retries: a worker must not hang on a dead store.
        config = Config(
            s3={"addressing_style": "path"},
            retries={"max_attempts": 4, "mode": "standard"},
            connect_timeout=10,
            read_timeout=60,
        )
        self._client: Any = session.client("s3", endpoint_url=endpoint_url, config=config)
        self._transfer = TransferConfig(
            multipart_threshold=MULTIPART_THRESHOLD, multipart_chunksize=MULTIPART_THRESHOLD
        )

    @property
    def location(self) -> str:
        """``s3://bucket/prefix`` (and the endpoint when not AWS's)."""
        where = f"s3://{self.bucket}/{self.prefix}".rstrip("/")
        return where + (f" at {self.endpoint_url}" if self.endpoint_url else "")

    def _key(self, key: str) -> str:
        return f"{self.prefix}/{key}" if self.prefix else key

    def check(self) -> None:
        """Raise ``ArtifactStoreError`` unless the bucket exists and answers these
        credentials (one ``HeadBucket``)."""
        self._call(
            "check the bucket",
            self._client.head_bucket,
            Bucket=self.bucket,
            probe=lambda: self._client.list_objects_v2(Bucket=self.bucket, MaxKeys=1),
        )

    def put_file(self, key: str, path: Path) -> None:
        """Upload ``path`` (in parts when large: the object appears only once complete)."""
        self._call(
            f"store {key}", self._client.upload_file, str(path), self.bucket, self._key(key),
            Config=self._transfer,
        )  # fmt: skip

    def get_file(self, key: str, path: Path) -> None:
        """Download ``key`` to ``path`` through a partial file renamed into place."""
        path.parent.mkdir(parents=True, exist_ok=True)
        # A name of its own: two requests fetching one file at once must not share a partial.
        partial = path.with_name(f"{path.name}.{uuid.uuid4().hex[:8]}{PARTIAL_SUFFIX}")
        try:
            self._call(
                f"read {key}", self._client.download_file, self.bucket, self._key(key),
                str(partial), Config=self._transfer, probe=self._probe(key),
            )  # fmt: skip
            os.replace(partial, path)
        finally:
            partial.unlink(missing_ok=True)

    def exists(self, key: str) -> bool:
        """One ``HeadObject``."""
        try:
            self._call(f"look up {key}", self._client.head_object,
                       Bucket=self.bucket, Key=self._key(key), probe=self._probe(key))  # fmt: skip
        except ArtifactMissing:
            return False
        return True

    def sizes(self, prefix: str) -> dict[str, int]:
        """Every object under ``prefix`` (keys relative to the store's prefix)."""
        return {item["Key"]: int(item["Size"]) for item in self._list(prefix)}

    def modified(self, prefix: str) -> dict[str, float]:
        """Every object under ``prefix`` and when it was stored."""
        return {item["Key"]: item["LastModified"].timestamp() for item in self._list(prefix)}

    def _list(self, prefix: str) -> list[dict[str, Any]]:
        """The listing of ``prefix`` (keys made relative to the store's prefix)."""
        strip = len(self._key(""))
        paginator = self._client.get_paginator("list_objects_v2")
        pages = paginator.paginate(Bucket=self.bucket, Prefix=self._key(prefix))
        items = []
        for page in self._call(f"list {prefix}", list, pages):
            for item in page.get("Contents", []):
                items.append({**item, "Key": item["Key"][strip:]})
        return items

    def delete_prefix(self, prefix: str) -> int:
        """Delete the objects under ``prefix`` (1000 per request)."""
        keys = [self._key(k) for k in self.sizes(prefix)]
        for start in range(0, len(keys), 1000):
            batch = [{"Key": k} for k in keys[start : start + 1000]]
            self._call(f"delete {prefix}", self._client.delete_objects,
                       Bucket=self.bucket, Delete={"Objects": batch, "Quiet": True})  # fmt: skip
        return len(keys)

    def _probe(self, key: str) -> Callable[[], Any]:
        """A one-byte GET of ``key``: its error body names what a HEAD's bare status does
        not (``NoSuchKey`` or ``NoSuchBucket``, ``SignatureDoesNotMatch`` or
        ``InvalidAccessKeyId``)."""
        return lambda: self._client.get_object(
            Bucket=self.bucket, Key=self._key(key), Range="bytes=0-0"
        )

    def _call(
        self, what: str, func: Any, *args: Any, probe: Callable[[], Any] | None = None,
        **kwargs: Any,
    ) -> Any:  # fmt: skip
        """``func(*args, **kwargs)`` with boto's errors turned into ours, each naming the
        store and the cause (asking ``probe`` for it when the answer was a bare status)."""
        from boto3.exceptions import S3UploadFailedError
        from botocore.exceptions import BotoCoreError, ClientError, NoCredentialsError

        try:
            return func(*args, **kwargs)
        except ClientError as first:
            exc = first
            if probe is not None and str(exc.response.get("Error", {}).get("Code")).isdigit():
                try:
                    probe()
                except ClientError as detailed:
                    exc = detailed
            error = exc.response.get("Error", {})
            code = str(error.get("Code", ""))
            message = error.get("Message") or exc.response.get("ResponseMetadata", {}).get(
                "HTTPStatusCode", ""
            )
            if code in MISSING_CODES:
                raise ArtifactMissing(f"{what}: no such object in {self.location}") from first
            if code in REFUSED_CODES:
                raise ArtifactRefused(
                    f"the artifact store {self.location} refused the credentials "
                    f"({code}: {message}) trying to {what}: check SPARSESPLAT_S3_ACCESS_KEY_ID "
                    "/ SPARSESPLAT_S3_SECRET_ACCESS_KEY (or AWS_ACCESS_KEY_ID / "
                    "AWS_SECRET_ACCESS_KEY)"
                ) from exc
            if code == "NoSuchBucket":
                raise ArtifactStoreError(
                    f"the bucket {self.bucket!r} does not exist at the artifact store "
                    f"{self.location} (trying to {what}): create it first"
                ) from exc
            raise ArtifactStoreError(
                f"the artifact store {self.location} failed to {what}: {code}: {message}"
            ) from exc
        except S3UploadFailedError as exc:  # upload_file wraps the ClientError in its text
            text = str(exc)
            if any(code in text for code in REFUSED_CODES - {"403"}):
                raise ArtifactRefused(
                    f"the artifact store {self.location} refused the credentials trying to "
                    f"{what}: {text}"
                ) from exc
            raise ArtifactStoreError(f"the artifact store {self.location} failed to {what}: "
                                     f"{text}") from exc  # fmt: skip
        except NoCredentialsError as exc:
            raise ArtifactRefused(
                f"no credentials for the artifact store {self.location}: set "
                "SPARSESPLAT_S3_ACCESS_KEY_ID and SPARSESPLAT_S3_SECRET_ACCESS_KEY (or "
                "AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY)"
            ) from exc
        except BotoCoreError as exc:  # the endpoint cannot be reached, a timeout, ...
            raise ArtifactStoreError(
                f"cannot {what} at the artifact store {self.location}: {exc}"
            ) from exc
