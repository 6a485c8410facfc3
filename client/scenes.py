"""What a job uploads, built from a dataset folder or from images plus cameras — without torch.

:func:`read_scene` reads every format the engine reads, through the same readers
(:mod:`sparsesplat.api.scenes`: file layouts, the paper's splits, each format's cameras), and
picks the paper's training views:

- ``folder`` (``cameras.json``, the service's upload format): frames with split ``train``
  (default all of them), held out: split ``test``;
- ``llff`` (``poses_bounds.npy`` + ``images_8/`` or the next folder the engine prefers): 3
  views evenly among images with i % 8 != 0, held out: i % 8 == 0;
- ``blender`` (``transforms_{train,test}.json``): train frames 26, 86, 2, 55, 75, 93, 16, 73
  (first 8), held out: every 8th frame of the test split;
- ``dtu`` (``cameras_sphere.npz`` + ``images/``): cameras 25, 22, 28 (first 3 of the RegNeRF
  order), held out: the 25 RegNeRF test ids;
- ``ngp`` (``transforms.json``): the LLFF rule over frames sorted by file path (3 views).

The JSON formats need nothing beyond the base install. ``poses_bounds.npy`` / ``.npz`` files,
images other than PNG/JPEG/WebP, ``downscale`` and lens undistortion (instant-ngp ``k1, k2,
p1, p2``) need the ``images`` extra (NumPy, Pillow). DTU object masks (``mask/NNN.png``) go up
with the held-out frames (the frame's ``mask``), so a DTU job's held-out PSNR is the paper's
object-masked one.
"""

from __future__ import annotations

import json
import posixpath
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from sparsesplat.api.cameras import CamerasFile, PinholeCamera, describe_validation_error
from sparsesplat.api.scenes import dtu, llff, transforms
from sparsesplat.api.scenes.errors import SceneFormatError
from sparsesplat.api.scenes.formats import (
    FORMAT_PRESETS,
    MARKERS,
    PAPER_VIEWS,
    SceneFormat,
    check_format,
    detect_format,
    list_images,
)
from sparsesplat.api.scenes.splits import (
    BLENDER_TEST_STRIDE,
    BLENDER_TRAIN_ORDER,
    DTU_TEST,
    DTU_TRAIN_ORDER,
    LLFF_HOLDOUT,
    TestViews,
    blender_split,
    check_view_count,
    dtu_split,
    evenly,
    llff_split,
    pick_tests,
)
from sparsesplat.client import media
from sparsesplat.client.errors import InvalidInput

PRESETS = FORMAT_PRESETS
"""The training preset a job from each format gets unless its spec names one."""


@dataclass
class Upload:
    """A job's upload: ``cameras.json`` and the files it names, ready to send."""

    cameras: dict[str, Any]
    """The cameras.json document (validated by :class:`~sparsesplat.api.cameras.CamerasFile`)."""
    images: dict[str, bytes]
    """Image bytes by the file name the frames use."""
    depths: dict[str, bytes] = field(default_factory=dict)
    """Depth maps by file name (optional)."""
    masks: dict[str, bytes] = field(default_factory=dict)
    """Object masks by file name (optional; a held-out frame with one is scored on the
    object only)."""
    preset: str | None = None
    """Training preset for the source format (None: the server decides)."""
    source: str = "images"
    """Where it came from (a folder path and its format), for messages."""
    train_indices: list[int] = field(default_factory=list)
    """Indices of the training views in the source's own numbering."""
    test_indices: list[int] = field(default_factory=list)
    """Indices of the attached held-out views in the source's own numbering."""

    @property
    def n_train(self) -> int:
        """Training frames."""
        return sum(f.get("split", "train") == "train" for f in self.cameras["frames"])

    @property
    def n_test(self) -> int:
        """Held-out frames."""
        return sum(f.get("split") == "test" for f in self.cameras["frames"])

    def test_cameras(self) -> list[PinholeCamera]:
        """The held-out views as render cameras (to compare renders with their images)."""
        return [self.camera(f["image"]) for f in self.cameras["frames"] if f.get("split") == "test"]

    def train_cameras(self) -> list[PinholeCamera]:
        """The training views as render cameras."""
        return [
            self.camera(f["image"])
            for f in self.cameras["frames"]
            if f.get("split", "train") == "train"
        ]

    def image_array(
        self, image: str, background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ) -> Any:
        """The uploaded image ``image`` as an (H, W, 3) uint8 array, an alpha channel
        composited on ``background`` (white, as the service does for images with alpha);
        ``images`` extra."""
        return media.composite_on(media.decode_image(self.images[image]), background)

    def test_images(self, background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> list[Any]:
        """The held-out images as arrays, in the order of :meth:`test_cameras`."""
        return [self.image_array(n, background) for n in self.frame_names("test")]

    def camera(self, image: str) -> PinholeCamera:
        """The render camera of the frame whose image is ``image``."""
        for frame in self.cameras["frames"]:
            if frame["image"] == image:
                width, height = frame.get("width"), frame.get("height")
                if width is None or height is None:
                    width, height = media.image_size(self.images[image], image)
                return PinholeCamera(
                    convention=self.cameras["convention"],
                    pose=self.cameras["pose"],
                    matrix=frame["matrix"],
                    fx=frame["fx"],
                    fy=frame["fy"],
                    cx=frame["cx"],
                    cy=frame["cy"],
                    width=width,
                    height=height,
                )
        raise KeyError(image)

    def frame_names(self, split: str) -> list[str]:
        """Image names of the frames of ``split`` in upload order."""
        return [f["image"] for f in self.cameras["frames"] if f.get("split", "train") == split]

    def validate(self) -> Upload:
        """Check cameras.json against the schema and the files against the frames."""
        try:
            CamerasFile.model_validate(self.cameras)
        except ValidationError as exc:
            raise InvalidInput(
                f"{self.source}: cameras: {describe_validation_error(exc, self.cameras)}"
            ) from exc
        names = [posixpath.basename(f["image"]) for f in self.cameras["frames"]]
        missing = sorted(set(names) - set(self.images))
        if missing:
            raise InvalidInput(f"{self.source}: no image for frame(s) {', '.join(missing[:5])}")
        for kind, files in (("depth", self.depths), ("mask", self.masks)):
            named = [posixpath.basename(f[kind]) for f in self.cameras["frames"] if f.get(kind)]
            absent = sorted(set(named) - set(files))
            if absent:
                raise InvalidInput(f"{self.source}: no {kind} file {', '.join(absent[:5])}")
        return self


# ---------------------------------------------------------------- reading folders


def read_scene(
    path: str | Path,
    *,
    views: int | None = None,
    test_views: TestViews = "all",
    downscale: int = 1,
    format: SceneFormat | None = None,
) -> Upload:
    """An :class:`Upload` of the scene folder ``path`` with the paper's split.

    Args:
        path: the scene folder (any format in this module's table).
        views: training views; None: the paper's count for the format (an upload folder: all
            its training frames).
        test_views: held-out views to attach (scored while training, for the error-against-
            time record): ``"all"`` of the split's, a number taken evenly, or 0 for none.
        downscale: integer factor to shrink every image by before upload (intrinsics follow);
            needs the ``images`` extra.
        format: force a format instead of detecting it from the marker files.
    """
    root = Path(path)
    if not isinstance(downscale, int) or downscale < 1:
        raise InvalidInput(f"downscale must be an integer >= 1, got {downscale!r}")
    try:
        fmt = check_format(format, str(root)) if format else detect_format(root)
        reader = {
            "folder": _read_folder,
            "llff": _read_llff,
            "blender": _read_blender,
            "dtu": _read_dtu,
            "ngp": _read_ngp,
        }[fmt]
        upload = reader(root, views, test_views)
    except SceneFormatError as exc:
        raise InvalidInput(str(exc)) from exc
    upload.source = f"{root} ({fmt})"
    upload.preset = PRESETS.get(fmt)
    if downscale != 1:
        _downscale(upload, downscale)
    return upload.validate()


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InvalidInput(f"{path}: cannot read ({exc})") from exc


def _uploadable(data: bytes, name: str) -> tuple[bytes, str]:
    """(bytes the service accepts, upload file name): PNG/JPEG/WebP as they are, other
    formats converted to PNG (images extra)."""
    if media.sniff(data) is not None:
        return data, name
    return media.to_png(data), posixpath.splitext(name)[0] + ".png"


def _frame(
    name: str,
    matrix: Sequence[Sequence[float]],
    k: tuple[float, float, float, float],
    size: tuple[int, int],
    split: str,
) -> dict[str, Any]:
    return {
        "image": name,
        "matrix": [[float(x) for x in row] for row in matrix],
        "fx": float(k[0]),
        "fy": float(k[1]),
        "cx": float(k[2]),
        "cy": float(k[3]),
        "width": int(size[0]),
        "height": int(size[1]),
        "split": split,
    }


def _read_folder(root: Path, views: int | None, test_views: TestViews) -> Upload:
    path = root / "cameras.json"
    try:
        document = json.loads(path.read_text())
        cameras = CamerasFile.model_validate(document)
    except (OSError, ValueError) as exc:
        detail = (
            describe_validation_error(exc, document) if isinstance(exc, ValidationError) else exc
        )
        raise InvalidInput(f"{path}: {detail}") from exc
    frames = cameras.frames
    pool = [i for i, f in enumerate(frames) if f.split == "train"]
    tests = [i for i, f in enumerate(frames) if f.split == "test"]
    count = len(pool) if views is None else views
    check_view_count(count, len(pool), str(path))
    train = evenly(pool, count)
    chosen = train + pick_tests(tests, test_views)
    images: dict[str, bytes] = {}
    depths: dict[str, bytes] = {}
    masks: dict[str, bytes] = {}
    out_frames = []
    for i in chosen:
        frame = frames[i]
        data, name = _uploadable(_read(root / frame.image), posixpath.basename(frame.image))
        if name in images:
            raise InvalidInput(f"{path}: two frames' images are named {name!r}")
        images[name] = data
        entry = frame.model_dump(mode="json", exclude_none=True)
        entry["image"] = name
        if frame.depth:
            depth_name = posixpath.basename(frame.depth)
            depths[depth_name] = _read(root / frame.depth)
            entry["depth"] = depth_name
        if frame.mask:
            mask_name = posixpath.basename(frame.mask)
            masks[mask_name] = _read(root / frame.mask)
            entry["mask"] = mask_name
        out_frames.append(entry)
    document = cameras.model_dump(mode="json", exclude_none=True)
    document["frames"] = out_frames
    return Upload(
        document, images, depths, masks, train_indices=train, test_indices=chosen[len(train) :]
    )


def _numpy(what: str) -> Any:
    return media.require("numpy", what)


def _read_llff(root: Path, views: int | None, test_views: TestViews) -> Upload:
    _numpy("reading LLFF poses_bounds.npy")
    pb_path = root / "poses_bounds.npy"
    pb = llff.read_poses_bounds(pb_path)
    folder = llff.find_image_dir(root)
    files = list_images(folder)
    if len(pb) != len(files):
        raise SceneFormatError(f"{pb_path}: {len(pb)} poses but {len(files)} images in {folder}")
    train, test = llff_split(len(files), views or PAPER_VIEWS["llff"], str(root))
    chosen = train + pick_tests(test, test_views)
    images: dict[str, bytes] = {}
    frames = []
    for n, i in enumerate(chosen):
        data, name = _uploadable(_read(files[i]), files[i].name)
        width, height = media.image_size(data, name)
        k = llff.intrinsics(pb[i], width, height, f"{pb_path} row {i}")
        c2w = llff.camera_to_world(pb[i, :15].reshape(3, 5)[:, :4])
        images[name] = data
        split = "train" if n < len(train) else "test"
        frames.append(_frame(name, c2w.tolist(), k, (width, height), split))
        frames[-1]["near"], frames[-1]["far"] = float(pb[i, 15]), float(pb[i, 16])
    document = {
        "convention": "opencv",
        "pose": "camera_to_world",
        "frames": frames,
        # the depth range over every image of the capture, as the engine's LLFF loader takes it
        "near": float(pb[:, 15].min()),
        "far": float(pb[:, 16].max()),
    }
    return Upload(document, images, train_indices=train, test_indices=chosen[len(train) :])


def _read_blender(root: Path, views: int | None, test_views: TestViews) -> Upload:
    train_meta = transforms.read_transforms(root / "transforms_train.json")
    test_meta = transforms.read_transforms(root / "transforms_test.json")
    train, test = blender_split(
        len(train_meta["frames"]),
        len(test_meta["frames"]),
        views or PAPER_VIEWS["blender"],
        str(root),
    )
    chosen = [("train", train_meta, i) for i in train] + [
        ("test", test_meta, i) for i in pick_tests(test, test_views)
    ]
    images: dict[str, bytes] = {}
    frames = []
    for split, meta, i in chosen:
        source = f"{root}/transforms_{split}.json frame {i}"
        frame = meta["frames"][i]
        path = transforms.frame_image_path(root, frame, source)
        data, name = _uploadable(_read(path), f"{split}_{path.name}")
        width, height = media.image_size(data, name)
        k = transforms.intrinsics(meta, frame, width, height, source)
        images[name] = data
        frames.append(_frame(name, frame.get("transform_matrix"), k, (width, height), split))
    document = {
        "convention": "opengl",
        "pose": "camera_to_world",
        "frames": frames,
        "near": transforms.BLENDER_NEAR,
        "far": transforms.BLENDER_FAR,
        "init_box": [list(corner) for corner in transforms.UNIT_CUBE],
    }
    tests = [i for s, _, i in chosen if s == "test"]
    return Upload(document, images, train_indices=train, test_indices=tests)


def _read_ngp(root: Path, views: int | None, test_views: TestViews) -> Upload:
    path = root / "transforms.json"
    meta = transforms.read_transforms(path)
    frames_in = sorted(meta["frames"], key=lambda f: str(f.get("file_path")))
    train, test = llff_split(len(frames_in), views or PAPER_VIEWS["ngp"], str(root))
    chosen = train + pick_tests(test, test_views)
    images: dict[str, bytes] = {}
    frames = []
    for n, i in enumerate(chosen):
        frame = frames_in[i]
        source = f"{path} {frame.get('file_path')}"
        image_path = transforms.frame_image_path(root, frame, source)
        data, name = _uploadable(_read(image_path), image_path.name)
        width, height = media.image_size(data, name)
        k = transforms.intrinsics(meta, frame, width, height, source)
        coeffs = transforms.distortion(meta, frame, source)
        if any(coeffs):
            data, name = _undistort(data, k, coeffs), posixpath.splitext(name)[0] + ".png"
        images[name] = data
        split = "train" if n < len(train) else "test"
        frames.append(_frame(name, frame.get("transform_matrix"), k, (width, height), split))
    document = {"convention": "opengl", "pose": "camera_to_world", "frames": frames}
    return Upload(document, images, train_indices=train, test_indices=chosen[len(train) :])


def _undistort(
    data: bytes, k: tuple[float, float, float, float], coeffs: tuple[float, float, float, float]
) -> bytes:
    """Resample an image taken through an OpenCV radial-tangential lens into the ideal
    pinhole image with the same intrinsics (bilinear, black outside), as the engine does."""
    np = _numpy("undistorting instant-ngp images (k1, k2, p1, p2)")
    image = np.asarray(media.decode_image(data).convert("RGB"), dtype=np.float32)
    h, w = image.shape[:2]
    xs, ys = transforms.distorted_pixels(w, h, k, coeffs)
    xs, ys = xs - 0.5, ys - 0.5  # continuous coordinates -> pixel-centre indices
    x0, y0 = np.floor(xs).astype(np.int64), np.floor(ys).astype(np.int64)
    out = np.zeros_like(image)
    for dy in (0, 1):
        for dx in (0, 1):
            xi, yi = x0 + dx, y0 + dy
            weight = (1 - np.abs(xs - xi)) * (1 - np.abs(ys - yi))
            inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            sample = image[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)]
            out += sample * (weight * inside)[..., None]
    return media.encode_png((np.clip(out, 0, 255) + 0.5).astype(np.uint8))


def _read_dtu(root: Path, views: int | None, test_views: TestViews) -> Upload:
    np = _numpy("reading DTU cameras_sphere.npz")
    npz_path = root / "cameras_sphere.npz"
    cams = dtu.read_cameras(npz_path)
    files = list_images(dtu.image_folder(root))
    train, test = dtu_split(len(files), views or PAPER_VIEWS["dtu"], str(root))
    chosen = train + pick_tests(test, test_views)
    images: dict[str, bytes] = {}
    masks: dict[str, bytes] = {}
    frames = []
    poses = {
        i: dtu.decompose_projection(dtu.projection(cams, i, str(npz_path)), f"{npz_path} {i}")
        for i in train + test
    }
    # The scene's depth range as the engine's DTU loader sets it: the unit sphere NeuS's
    # scale_mat maps the object into, seen from every camera of the split.
    dists = [float(np.linalg.norm(w2c[:3, :3].T @ w2c[:3, 3])) for _, w2c in poses.values()]
    near, far = dtu.bounds(dists)
    bounds = {"near": near, "far": far, "init_box": [list(c) for c in transforms.UNIT_CUBE]}
    for n, i in enumerate(chosen):
        k, w2c = poses[i]
        data, name = _uploadable(_read(files[i]), files[i].name)
        width, height = media.image_size(data, name)
        images[name] = data
        split = "train" if n < len(train) else "test"
        intr = (float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))
        frames.append(_frame(name, w2c.tolist(), intr, (width, height), split))
        mask = dtu.mask_path(root, i, files[i]) if split == "test" else None
        if mask is not None:  # held-out frames are scored on the object, as in the paper
            masks[f"mask_{name}"], frames[-1]["mask"] = _read(mask), f"mask_{name}"
    document = {"convention": "opencv", "pose": "world_to_camera", "frames": frames, **bounds}
    return Upload(
        document, images, masks=masks, train_indices=train, test_indices=chosen[len(train) :]
    )


def _downscale(upload: Upload, factor: int) -> None:
    if upload.depths:
        raise InvalidInput(f"{upload.source}: downscale with depth maps is not supported")
    for frame in upload.cameras["frames"]:
        name = frame["image"]
        width, height = media.image_size(upload.images[name], name)
        new_w, new_h = max(1, width // factor), max(1, height // factor)
        upload.images[name] = media.resize(upload.images[name], new_w, new_h)
        new_name = posixpath.splitext(name)[0] + ".png"
        if new_name != name:
            upload.images[new_name] = upload.images.pop(name)
        mask = frame.get("mask")
        if mask is not None:  # shrunk like the image; the loader thresholds it at half
            upload.masks[mask] = media.resize(upload.masks[mask], new_w, new_h)
        frame.update(
            image=new_name,
            width=new_w,
            height=new_h,
            fx=frame["fx"] * new_w / width,
            fy=frame["fy"] * new_h / height,
            cx=frame["cx"] * new_w / width,
            cy=frame["cy"] * new_h / height,
        )


# ---------------------------------------------------------------- images + cameras


def from_images(
    images: Sequence[Any],
    cameras: Sequence[PinholeCamera],
    *,
    test_images: Sequence[Any] = (),
    test_cameras: Sequence[PinholeCamera] = (),
    names: Sequence[str] | None = None,
    near: float | None = None,
    far: float | None = None,
    init_box: tuple[Sequence[float], Sequence[float]] | None = None,
) -> Upload:
    """An :class:`Upload` of images with their cameras.

    ``near``/``far`` (the scene's depth range from the cameras) and ``init_box`` (the box the
    scene lies in: minimum corner, maximum corner) go into ``cameras.json`` when given; the
    service estimates them from the cameras otherwise (docs/cameras.md).

    Each image is a file path (PNG/JPEG/WebP sent as they are), encoded bytes, a NumPy array
    (H, W, 3|4; uint8 or float in [0, 1]) or a PIL image (arrays and PIL images need the
    ``images`` extra). Cameras are :class:`PinholeCamera` (see :mod:`sparsesplat.client.cameras`
    to build them from 4x4 matrices); their size must match the image. All cameras of one
    upload share one ``convention`` and ``pose`` direction (converted if they differ)."""
    if len(images) != len(cameras):
        raise InvalidInput(f"{len(images)} images but {len(cameras)} cameras")
    if len(test_images) != len(test_cameras):
        raise InvalidInput(f"{len(test_images)} test images but {len(test_cameras)} cameras")
    all_cams = list(cameras) + list(test_cameras)
    if not all_cams:
        raise InvalidInput("no images")
    convention, pose = all_cams[0].convention, all_cams[0].pose
    uploaded: dict[str, bytes] = {}
    frames = []
    given = list(names) if names is not None else None
    for n, (image, cam) in enumerate(zip([*images, *test_images], all_cams, strict=True)):
        split = "train" if n < len(images) else "test"
        data, name = _image_bytes(image, n, split)
        if given is not None:
            name = given[n]
        if name in uploaded:
            name = f"{split}_{n:03d}_{name}"
        width, height = media.image_size(data, name)
        if (width, height) != (cam.width, cam.height):
            raise InvalidInput(
                f"{name}: the image is {width}x{height} but its camera says "
                f"{cam.width}x{cam.height}"
            )
        matrix = cam.matrix
        if (cam.convention, cam.pose) != (convention, pose):
            matrix = _convert(cam, convention, pose)
        uploaded[name] = data
        frames.append(
            _frame(name, matrix, (cam.fx, cam.fy, cam.cx, cam.cy), (width, height), split)
        )
    document: dict[str, Any] = {
        "convention": convention.value,
        "pose": pose.value,
        "frames": frames,
    }
    bounds = {"near": near, "far": far, "init_box": init_box}
    document.update({k: v for k, v in bounds.items() if v is not None})
    return Upload(document, uploaded, source="images").validate()


def _image_bytes(image: Any, n: int, split: str) -> tuple[bytes, str]:
    if isinstance(image, str | Path):
        path = Path(image)
        return _uploadable(_read(path), path.name)
    if isinstance(image, bytes | bytearray):
        data = bytes(image)
        kind = media.sniff(data)
        if kind is None:
            return media.to_png(data), f"{split}_{n:03d}.png"
        return data, f"{split}_{n:03d}.{'jpg' if kind == 'jpeg' else kind}"
    return media.encode_png(image, "an image array"), f"{split}_{n:03d}.png"


def _convert(cam: PinholeCamera, convention: Any, pose: Any) -> list[list[float]]:
    from sparsesplat.api.cameras import AxisConvention, PoseDirection, rigid_inverse
    from sparsesplat.client.cameras import camera_to_world_opencv

    m = camera_to_world_opencv(cam)
    if AxisConvention(convention) == AxisConvention.opengl:
        m = [[r[0], -r[1], -r[2], r[3]] for r in m]
    if PoseDirection(pose) == PoseDirection.world_to_camera:
        m = rigid_inverse(m)
    return m


__all__ = [
    "BLENDER_TEST_STRIDE",
    "BLENDER_TRAIN_ORDER",
    "DTU_TEST",
    "DTU_TRAIN_ORDER",
    "LLFF_HOLDOUT",
    "MARKERS",
    "PAPER_VIEWS",
    "PRESETS",
    "SceneFormat",
    "TestViews",
    "Upload",
    "blender_split",
    "dtu_split",
    "from_images",
    "llff_split",
    "read_scene",
]
