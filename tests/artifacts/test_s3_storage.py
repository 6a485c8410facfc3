"""The artifact store on a real S3-protocol server (moto's, on loopback): job files go up
and come back whole, a large model in parts; a missing object, a refused credential and a
missing bucket are typed errors naming the cause, and lose nothing already stored."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from sparsesplat.api.artifacts import ArtifactMissing, ArtifactRefused, ArtifactStoreError
from sparsesplat.api.settings import load_settings
from sparsesplat.api.storage import Storage
from tests.artifacts.moto_s3 import MotoS3

JOB = "job_" + "0123456789abcdef0123"


def storage(s3: MotoS3, root: Path, bucket: str, **override: str) -> Storage:
    """A machine's Storage on ``bucket`` (its own ``root``), from settings as a user sets
    them."""
    env = {k.removeprefix("SPARSESPLAT_").lower(): v for k, v in s3.settings_env(bucket).items()}
    return Storage.for_settings(load_settings(data_dir=root, **(env | override)))


def write_artifact(store: Storage, kind: str, data: bytes) -> Path:
    """``data`` written where ``store`` keeps the job's ``kind`` file, as a trainer writes it
    (not published); its path."""
    path = store.artifact(JOB, kind)
    path.parent.mkdir(parents=True)
    path.write_bytes(data)
    return path


def test_a_large_model_goes_up_in_parts_and_comes_back_whole_on_another_machine(
    s3: MotoS3, tmp_path: Path
) -> None:
    bucket = s3.new_bucket()
    worker, server = storage(s3, tmp_path / "w", bucket), storage(s3, tmp_path / "s", bucket)
    # > 16 MB: three parts of 8 MiB
    model = write_artifact(worker, "ply", os.urandom(20 * 2**20 + 123))
    worker.publish(model)

    head = s3.client().head_object(Bucket=bucket, Key=f"deploy/jobs/{JOB}/run/model.ply")
    assert head["ContentLength"] == model.stat().st_size
    assert head["ETag"].strip('"').endswith("-3"), "not a multipart upload"
    assert not list(model.parent.glob("*.tmp")), "the upload's snapshot link was left behind"

    fetched = server.fetch(server.artifact(JOB, "ply"))
    assert fetched == tmp_path / "s" / "jobs" / JOB / "run" / "model.ply"
    digest = hashlib.sha256
    assert digest(fetched.read_bytes()).digest() == digest(model.read_bytes()).digest()
    assert server.job_bytes(JOB) == model.stat().st_size


def test_upload_checkpoint_usage_and_delete(s3: MotoS3, tmp_path: Path) -> None:
    bucket = s3.new_bucket()
    api, worker = storage(s3, tmp_path / "api", bucket), storage(s3, tmp_path / "w", bucket)
    staging = api.new_staging_dir()
    (staging / "images").mkdir()
    (staging / "cameras.json").write_text("{}")
    (staging / "images" / "000.png").write_bytes(b"png" * 100)
    api.commit_upload(staging, JOB)
    assert set(s3.objects(bucket)) == {
        f"deploy/jobs/{JOB}/upload/cameras.json",
        f"deploy/jobs/{JOB}/upload/images/000.png",
    }

    worker.fetch_upload(JOB)
    assert (worker.upload_dir(JOB) / "images" / "000.png").read_bytes() == b"png" * 100
    assert not worker.fetch_checkpoint(JOB), "no checkpoint stored yet"
    checkpoint = worker.artifact(JOB, "checkpoint")
    checkpoint.parent.mkdir(parents=True, exist_ok=True)
    checkpoint.write_bytes(b"iteration 20")
    worker.publish(checkpoint)

    # Another machine that trained the job less far has an older checkpoint: the stored one wins.
    other = storage(s3, tmp_path / "w2", bucket)
    stale = write_artifact(other, "checkpoint", b"iteration 5")
    assert other.fetch_checkpoint(JOB)
    assert stale.read_bytes() == b"iteration 20"

    assert api.job_bytes(JOB) == 2 + 300 + len(b"iteration 20")
    assert api.has(api.artifact(JOB, "checkpoint")) and not api.has(api.artifact(JOB, "ply"))
    api.delete_job(JOB)
    assert s3.objects(bucket) == {} and not api.job_dir(JOB).exists()
    assert api.job_bytes(JOB) == 0


def test_a_missing_object_is_a_typed_not_found(s3: MotoS3, tmp_path: Path) -> None:
    store = storage(s3, tmp_path, s3.new_bucket())
    with pytest.raises(ArtifactMissing, match="no such object"):
        store.fetch(store.artifact(JOB, "splat"))
    assert not store.artifact(JOB, "splat").exists()
    assert not list(tmp_path.rglob("*.tmp")), "a partial download was left behind"
    with pytest.raises(ArtifactMissing, match=f"nothing stored under jobs/{JOB}/upload"):
        store.fetch_upload(JOB)


@pytest.mark.parametrize(
    ("override", "cause"),
    [
        ({"s3_secret_access_key": "not-the-secret"}, "SignatureDoesNotMatch"),
        ({"s3_access_key_id": "AKIAUNKNOWNKEY000000"}, "InvalidAccessKeyId"),
    ],
)
def test_a_refused_credential_names_the_cause_and_loses_nothing(
    s3: MotoS3, tmp_path: Path, override: dict[str, str], cause: str
) -> None:
    bucket = s3.new_bucket()
    good = storage(s3, tmp_path / "good", bucket)
    model = write_artifact(good, "ply", b"the model")
    good.publish(model)

    bad = storage(s3, tmp_path / "bad", bucket, **override)
    with pytest.raises(ArtifactRefused, match="refused the credentials") as refused:
        bad.check()
    assert "SPARSESPLAT_S3_SECRET_ACCESS_KEY" in str(refused.value)
    with pytest.raises(ArtifactRefused, match=cause):
        bad.fetch(bad.artifact(JOB, "ply"))
    with pytest.raises(ArtifactRefused, match=cause):
        bad.delete_job(JOB)
    overwrite = bad.artifact(JOB, "ply")
    overwrite.parent.mkdir(parents=True, exist_ok=True)
    overwrite.write_bytes(b"an overwrite attempt")
    with pytest.raises(ArtifactRefused, match=cause):
        bad.publish(overwrite)
    # What was stored is untouched.
    assert s3.objects(bucket) == {f"deploy/jobs/{JOB}/run/model.ply": len(b"the model")}
    again = storage(s3, tmp_path / "again", bucket)
    assert again.fetch(again.artifact(JOB, "ply")).read_bytes() == b"the model"


def test_a_missing_bucket_and_an_unreachable_store_are_named(s3: MotoS3, tmp_path: Path) -> None:
    store = storage(s3, tmp_path / "a", "no-such-bucket")
    with pytest.raises(ArtifactStoreError, match="bucket 'no-such-bucket' does not exist"):
        store.fetch(store.artifact(JOB, "ply"))
    dead = storage(s3, tmp_path / "b", "any", s3_endpoint_url="http://127.0.0.1:9")
    with pytest.raises(ArtifactStoreError, match="cannot check the bucket"):
        dead.check()


def test_without_a_location_files_stay_local(tmp_path: Path) -> None:
    store = Storage.for_settings(load_settings(data_dir=tmp_path))
    assert store.remote is None
    store.check()
    with pytest.raises(ArtifactMissing):
        store.fetch(store.artifact(JOB, "ply"))
    path = write_artifact(store, "ply", b"12345")
    assert store.fetch(path) == path and store.has(path) and store.job_bytes(JOB) == 5


def test_the_location_setting_is_checked() -> None:
    with pytest.raises(ValueError, match="s3://BUCKET/PREFIX"):
        load_settings(artifacts="/mnt/shared")
    with pytest.raises(ValueError, match="no bucket"):
        load_settings(artifacts="s3:///prefix")


def test_a_running_job_stores_what_resume_and_the_server_need(s3: MotoS3, tmp_path: Path) -> None:
    from sparsesplat.worker.artifact_sync import RunSync

    bucket = s3.new_bucket()
    worker = storage(s3, tmp_path, bucket)
    run = worker.run_dir(JOB)
    (run / "priors").mkdir(parents=True)
    files = {
        "checkpoint.pt": b"iteration 10",
        "metrics_series.png": b"plot",
        "priors/view_000.png": b"prior picture",
        "priors/cache_0.npz": b"prior cache",  # scratch: never stored
        "checkpoint.pt.tmp": b"half a checkpoint",  # partial: never stored
    }
    for name, data in files.items():
        (run / name).write_bytes(data)
    lease = {"held": True}
    sync = RunSync(worker, JOB, allowed=lambda: lease["held"])
    assert sync.push_changed() == 3
    stored = s3.objects(bucket, f"deploy/jobs/{JOB}/run/")
    assert {k.rsplit("/run/", 1)[1] for k in stored} == {
        "checkpoint.pt", "metrics_series.png", "priors/view_000.png"
    }  # fmt: skip
    assert sync.push_changed() == 0, "unchanged files went up again"

    (run / "checkpoint.pt.tmp").replace(run / "checkpoint.pt")  # the trainer's next one
    assert sync.push_changed() == 1
    lease["held"] = False  # the job is another worker's now: an older checkpoint stays here
    (run / "checkpoint.pt").write_bytes(b"iteration 3")
    assert sync.push_changed() == 0
    again = storage(s3, tmp_path / "other", bucket)
    assert again.fetch_checkpoint(JOB)
    assert again.artifact(JOB, "checkpoint").read_bytes() == b"half a checkpoint"


def test_jobs_known_only_to_the_bucket_are_found_for_the_stray_sweep(
    s3: MotoS3, tmp_path: Path
) -> None:
    import time

    bucket = s3.new_bucket()
    worker, api = storage(s3, tmp_path / "w", bucket), storage(s3, tmp_path / "api", bucket)
    left = b"left by a worker killed after its job was deleted"
    path = write_artifact(worker, "checkpoint", left)
    before = time.time()
    worker.publish(path)
    stored = api.stored_jobs()
    assert set(stored) == {JOB}, "the API has no folder of it: only the bucket knows it"
    assert abs(stored[JOB] - before) < 60  # the store's clock: a sweep waits 10 minutes
    api.delete_job(JOB)
    assert api.stored_jobs() == {} and s3.objects(bucket) == {}
