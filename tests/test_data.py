"""Tests of vehicle_detection.training.data: the training set from the real archives and from fake ones."""

from __future__ import annotations

import hashlib
import io
import zipfile
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vehicle_detection.training.data import DATA_ENV, default_data_dir, find_duplicates, load_dataset
from vehicle_detection.errors import InputError

# the training archives are loaded once a worker (session fixtures): their tests share one
pytestmark = pytest.mark.xdist_group("archives")

# From the data README (and the Udacity project description).
EXPECTED_COUNTS = {
    "vehicles/GTI_Far": 834,
    "vehicles/GTI_Left": 909,
    "vehicles/GTI_MiddleClose": 419,
    "vehicles/GTI_Right": 664,
    "vehicles/KITTI_extracted": 5966,
    "non-vehicles/GTI": 3900,
    "non-vehicles/Extras": 5068,
}


def _png(seed: int, size=(64, 64)) -> bytes:
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _zip(path: Path, members: dict[str, bytes], compression=zipfile.ZIP_DEFLATED) -> Path:
    with zipfile.ZipFile(path, "w", compression=compression) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def _fake_data(root: Path, vehicles: dict[str, bytes] | None = None, non_vehicles: dict[str, bytes] | None = None) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    _zip(root / "vehicles.zip", vehicles if vehicles is not None else {"vehicles/A/image0.png": _png(1)})
    _zip(root / "non-vehicles.zip", non_vehicles if non_vehicles is not None else {"non-vehicles/B/image0.png": _png(2)})
    return root


# --------------------------------------------------------------------------------------------
# The real data set
# --------------------------------------------------------------------------------------------
def test_counts_per_folder(dataset):
    assert Counter(dataset.sources.tolist()) == EXPECTED_COUNTS
    assert dataset.counts() == dict(sorted(EXPECTED_COUNTS.items()))
    assert len(dataset) == 8792 + 8968
    assert int((dataset.labels == 1).sum()) == 8792
    assert int((dataset.labels == 0).sum()) == 8968


def test_arrays_and_labels(dataset):
    n = len(dataset)
    assert dataset.images.dtype == np.uint8 and dataset.images.shape == (n, 64, 64, 3)
    assert dataset.labels.shape == dataset.sources.shape == dataset.names.shape == dataset.groups.shape == dataset.digests.shape == (n,)
    assert dataset.groups.dtype == np.int64
    is_vehicle = np.array([s.startswith("vehicles/") for s in dataset.sources])
    np.testing.assert_array_equal(dataset.labels, is_vehicle.astype(np.int8))
    assert set(np.unique(dataset.labels).tolist()) == {0, 1}
    # Sources are the folders of the names.
    assert all(name.rsplit("/", 1)[0] == src for name, src in zip(dataset.names, dataset.sources))
    # Sorted: vehicles first, then folder, then file number.
    assert is_vehicle[:8792].all() and not is_vehicle[8792:].any()
    for src in EXPECTED_COUNTS:
        idx = np.flatnonzero(dataset.sources == src)
        assert np.all(np.diff(idx) == 1)  # each folder contiguous
        nums = [int("".join(ch for ch in name.rsplit("/", 1)[1] if ch.isdigit())) for name in dataset.names[idx]]
        assert nums == sorted(nums)


def test_names_and_pixels_match_the_archives(dataset, data_dir):
    names = {}
    for cls in ("vehicles", "non-vehicles"):
        with zipfile.ZipFile(data_dir / f"{cls}.zip") as zf:
            names[cls] = [n for n in zf.namelist() if n.endswith(".png")]
    assert set(dataset.names.tolist()) == set(names["vehicles"]) | set(names["non-vehicles"])
    assert len(set(dataset.names.tolist())) == len(dataset)
    # A sample decoded independently with Pillow; digests are SHA-1 of the member bytes.
    rng = np.random.default_rng(1)
    pos = {n: i for i, n in enumerate(dataset.names)}
    for cls in names:
        with zipfile.ZipFile(data_dir / f"{cls}.zip") as zf:
            for name in rng.choice(names[cls], 15, replace=False):
                data = zf.read(name)
                i = pos[name]
                np.testing.assert_array_equal(dataset.images[i], np.asarray(Image.open(io.BytesIO(data)).convert("RGB")))
                assert dataset.digests[i] == hashlib.sha1(data).hexdigest()


def _dup_groups(digests) -> list[list[int]]:
    by = defaultdict(list)
    for i, d in enumerate(digests):
        by[d].append(i)
    return sorted(g for g in by.values() if len(g) > 1)


def test_duplicates(dataset):
    dups = find_duplicates(dataset.digests)
    assert len(dups) == 189
    assert sum(len(g) for g in dups) == 378
    assert sorted(g.tolist() for g in dups) == _dup_groups(dataset.digests)
    kinds = Counter()
    for g in dups:
        assert np.all(np.diff(g) > 0)  # sorted
        assert len(set(dataset.labels[g].tolist())) == 1, "a duplicate crosses the classes"
        assert len(set(dataset.groups[g].tolist())) == 1, "a duplicate group straddles split groups"
        # Byte-identical files decode to identical pixels.
        assert all(np.array_equal(dataset.images[g[0]], dataset.images[j]) for j in g[1:])
        kinds[tuple(sorted(set(dataset.sources[g].tolist())))] += 1
    # Composition documented in the data README.
    assert kinds == {
        ("non-vehicles/Extras",): 173,
        ("vehicles/GTI_MiddleClose", "vehicles/GTI_Right"): 15,
        ("vehicles/GTI_Right",): 1,
    }


def _file_num(name: str) -> int:
    return int("".join(ch for ch in name.rsplit("/", 1)[1] if ch.isdigit()))


def test_groups_follow_folders_and_file_number_blocks(dataset):
    # A group is one folder's block of 100 consecutive file numbers, unless duplicates join blocks.
    keys = [(str(s), _file_num(n) // 100) for s, n in zip(dataset.sources, dataset.names)]
    groups_of_key = defaultdict(set)
    keys_of_group = defaultdict(set)
    for k, g in zip(keys, dataset.groups.tolist()):
        groups_of_key[k].add(g)
        keys_of_group[g].add(k)
    assert all(len(v) == 1 for v in groups_of_key.values())
    dup_groups = {int(dataset.groups[g[0]]) for g in find_duplicates(dataset.digests)}
    joined = {g for g, ks in keys_of_group.items() if len(ks) > 1}
    assert joined <= dup_groups
    assert joined  # the 15 GTI_MiddleClose/GTI_Right pairs do join blocks
    # GTI_Far (no duplicates) has one group per block of 100 file numbers.
    far = dataset.sources == "vehicles/GTI_Far"
    blocks = {_file_num(n) // 100 for n in dataset.names[far]}
    assert len(set(dataset.groups[far].tolist())) == len(blocks) >= 5


def test_grouped_split_never_separates_duplicates(dataset):
    from vehicle_detection.training.fit import split_indices

    train, test = split_indices(dataset.labels, dataset.groups, test_size=0.2, random_state=3)
    side = np.zeros(len(dataset), np.int8)
    side[test] = 1
    for g in find_duplicates(dataset.digests):
        assert len(set(side[g].tolist())) == 1


@pytest.fixture(scope="module")
def extracted(dataset, data_dir, tmp_path_factory):
    """A few hundred members of each archive, plus every duplicate file, extracted to a folder."""
    root = tmp_path_factory.mktemp("extracted")
    rng = np.random.default_rng(7)
    dup = {str(dataset.names[i]) for g in find_duplicates(dataset.digests) for i in g}
    chosen = set(dup)
    for cls in ("vehicles", "non-vehicles"):
        with zipfile.ZipFile(data_dir / f"{cls}.zip") as zf:
            names = [n for n in zf.namelist() if n.endswith(".png")]
            picks = set(rng.choice(names, 250, replace=False).tolist()) | {n for n in dup if n.startswith(cls + "/")}
            zf.extractall(root, members=sorted(picks))
            chosen |= picks
    return root, chosen


def test_load_from_extracted_folder(dataset, extracted):
    root, chosen = extracted
    assert not (root / "vehicles.zip").exists()
    sub = load_dataset(root)
    assert set(sub.names.tolist()) == chosen and len(sub) == len(chosen)
    pos = {n: i for i, n in enumerate(dataset.names)}
    idx = np.array([pos[n] for n in sub.names])
    assert np.all(np.diff(idx) > 0)  # same order as the full set
    np.testing.assert_array_equal(sub.images, dataset.images[idx])
    np.testing.assert_array_equal(sub.labels, dataset.labels[idx])
    np.testing.assert_array_equal(sub.sources, dataset.sources[idx])
    np.testing.assert_array_equal(sub.digests, dataset.digests[idx])


def test_drop_duplicates(dataset, extracted):
    # The extracted subset holds all 378 duplicate files, so dropping must remove exactly 189
    # files: all but the first (in data-set order) of each group.
    root, chosen = extracted
    full = load_dataset(root)
    dedup = load_dataset(root, drop_duplicates=True)
    assert len(full) - len(dedup) == 189
    drop = set()
    for g in _dup_groups(full.digests):
        drop |= {str(full.names[j]) for j in g[1:]}
    assert len(drop) == 189
    assert set(dedup.names.tolist()) == chosen - drop
    assert len(set(dedup.digests.tolist())) == len(dedup)  # no duplicate left
    keep = np.array([n not in drop for n in full.names])
    np.testing.assert_array_equal(dedup.images, full.images[keep])
    np.testing.assert_array_equal(dedup.groups, full.groups[keep])


# --------------------------------------------------------------------------------------------
# Fake archives: layout rules, grouping, refusals
# --------------------------------------------------------------------------------------------
def test_fake_archive_order_filtering_and_groups(tmp_path):
    dup_bytes = _png(100)
    vehicles = {f"vehicles/GTI_Far/image{k:04d}.png": _png(k) for k in range(25)}
    vehicles["vehicles/GTI_Far/image0003.png"] = dup_bytes
    vehicles["vehicles/GTI_Right/image0100.png"] = dup_bytes  # byte-identical to GTI_Far/image0003
    vehicles["vehicles/GTI_Right/image0101.png"] = _png(200)
    vehicles["vehicles/GTI_Far/._image0001.png"] = b"resource fork"  # hidden: ignored
    vehicles["vehicles/GTI_Far/notes.txt"] = b"not an image"  # ignored
    vehicles["__MACOSX/vehicles/GTI_Far/image0001.png"] = b"junk"  # outside vehicles/: ignored
    non_vehicles = {f"non-vehicles/Extras/extra{k}.png": _png(300 + k) for k in (10, 2, 1, 9)}
    root = _fake_data(tmp_path / "d", vehicles, non_vehicles)
    ds = load_dataset(root, track_length=10)
    assert ds.names.tolist() == (
        [f"vehicles/GTI_Far/image{k:04d}.png" for k in range(25)]
        + ["vehicles/GTI_Right/image0100.png", "vehicles/GTI_Right/image0101.png"]
        + [f"non-vehicles/Extras/extra{k}.png" for k in (1, 2, 9, 10)]
    )
    assert ds.labels.tolist() == [1] * 27 + [0] * 4
    # Groups by hand: GTI_Far 0-9 (joined with GTI_Right 100-109 through the duplicate),
    # GTI_Far 10-19, GTI_Far 20-24, Extras 0-9 (1, 2, 9) and Extras 10-19 (10).
    expected = [0] * 10 + [1] * 10 + [2] * 5 + [0, 0] + [3, 3, 3, 4]
    g = ds.groups
    for i in range(len(ds)):
        for j in range(len(ds)):
            assert (g[i] == g[j]) == (expected[i] == expected[j]), (ds.names[i], ds.names[j])
    assert [x.tolist() for x in find_duplicates(ds.digests)] == [[3, 25]]
    dedup = load_dataset(root, track_length=10, drop_duplicates=True)
    assert "vehicles/GTI_Right/image0100.png" not in dedup.names and len(dedup) == len(ds) - 1


def test_find_duplicates_by_hand():
    got = find_duplicates(np.array(["a", "b", "a", "c", "b", "a"]))
    assert sorted(x.tolist() for x in got) == [[0, 2, 5], [1, 4]]
    assert find_duplicates(np.array(["x", "y"])) == []
    assert find_duplicates(np.array([], dtype=str)) == []


def test_decoding_threads_give_the_set_one_thread_gives(tmp_path):
    """Threads decode runs of patches; the set, its order and a bad patch's error are those of one thread."""
    vehicles = {f"vehicles/A/image{k}.png": _png(k) for k in range(23)}
    non_vehicles = {f"non-vehicles/B/image{k}.png": _png(100 + k) for k in range(17)}
    one = load_dataset(_fake_data(tmp_path / "data", vehicles, non_vehicles), n_jobs=1)
    for n_jobs in (2, 3):
        threads = load_dataset(tmp_path / "data", n_jobs=n_jobs)
        assert np.array_equal(threads.images, one.images) and threads.names.tolist() == one.names.tolist()
        assert threads.digests.tolist() == one.digests.tolist() and threads.labels.tolist() == one.labels.tolist()
    assert len(one) == 40
    non_vehicles["non-vehicles/B/image9.png"] = _png(9, size=(32, 32))
    for n_jobs in (1, 3):
        with pytest.raises(InputError, match=r"image9\.png: training patches must be 64x64, got 32x32"):
            load_dataset(_fake_data(tmp_path / f"bad{n_jobs}", vehicles, non_vehicles), n_jobs=n_jobs)


def test_missing_data_folder(tmp_path):
    missing = tmp_path / "no-data-here"
    with pytest.raises(InputError) as info:
        load_dataset(missing)
    assert str(missing) in str(info.value)


def test_folder_without_archives(tmp_path):
    (tmp_path / "something.txt").write_text("x")
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(tmp_path) in str(info.value)
    assert "vehicles" in str(info.value)


def test_only_one_archive(tmp_path):
    _zip(tmp_path / "vehicles.zip", {"vehicles/A/image0.png": _png(1)})
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(tmp_path) in str(info.value) and "non-vehicles" in str(info.value)


def test_corrupt_zip(tmp_path):
    _fake_data(tmp_path)
    bad = tmp_path / "vehicles.zip"
    bad.write_bytes(b"PK\x03\x04 definitely not a zip archive" * 10)
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(bad) in str(info.value)


def test_truncated_zip(tmp_path):
    _fake_data(tmp_path, non_vehicles={f"non-vehicles/B/image{k}.png": _png(k) for k in range(5)})
    arc = tmp_path / "non-vehicles.zip"
    data = arc.read_bytes()
    arc.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(arc) in str(info.value)


def test_corrupt_member(tmp_path):
    # A stored (uncompressed) member with a flipped byte: the CRC check fails on reading.
    png = _png(5)
    arc = _zip(tmp_path / "vehicles.zip", {"vehicles/A/image0.png": png}, compression=zipfile.ZIP_STORED)
    _zip(tmp_path / "non-vehicles.zip", {"non-vehicles/B/image0.png": _png(6)})
    data = bytearray(arc.read_bytes())
    k = data.index(png[100:120]) + 5
    data[k] ^= 0xFF
    arc.write_bytes(bytes(data))
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(arc) in str(info.value) or str(tmp_path / "vehicles/A/image0.png") in str(info.value)


def test_wrong_size_patch_in_archive(tmp_path):
    _fake_data(
        tmp_path,
        vehicles={"vehicles/A/image0.png": _png(1), "vehicles/A/image1.png": _png(2, size=(32, 64))},
    )
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(tmp_path / "vehicles/A/image1.png") in str(info.value)
    assert "64x64" in str(info.value)


def test_non_image_png_in_archive(tmp_path):
    _fake_data(tmp_path, non_vehicles={"non-vehicles/B/image0.png": b"<html>404 not found</html>"})
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(tmp_path / "non-vehicles/B/image0.png") in str(info.value)


def test_archive_without_pngs(tmp_path):
    _fake_data(tmp_path, vehicles={"vehicles/readme.txt": b"x"})
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert str(tmp_path) in str(info.value)


def test_greyscale_png_in_archive_becomes_rgb(tmp_path):
    grey = np.random.default_rng(3).integers(0, 256, (64, 64), dtype=np.uint8)
    buf = io.BytesIO()
    Image.fromarray(grey).save(buf, format="PNG")
    _fake_data(tmp_path, vehicles={"vehicles/A/image0.png": buf.getvalue()})
    ds = load_dataset(tmp_path)
    assert ds.images.shape == (2, 64, 64, 3)
    np.testing.assert_array_equal(ds.images[0], np.repeat(grey[:, :, None], 3, axis=2))


# --------------------------------------------------------------------------------------------
# default_data_dir
# --------------------------------------------------------------------------------------------
def test_default_data_dir_order(tmp_path, monkeypatch):
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "from-env"))
    assert default_data_dir(tmp_path / "arg") == tmp_path / "arg"
    assert default_data_dir(str(tmp_path / "arg")) == tmp_path / "arg"
    assert default_data_dir() == tmp_path / "from-env"
    assert default_data_dir(None) == tmp_path / "from-env"
    monkeypatch.delenv(DATA_ENV)
    assert default_data_dir() == Path("data")


def test_load_dataset_uses_env_then_cwd(tmp_path, monkeypatch):
    env_root = _fake_data(tmp_path / "env")
    monkeypatch.setenv(DATA_ENV, str(env_root))
    assert len(load_dataset()) == 2
    monkeypatch.delenv(DATA_ENV)
    work = tmp_path / "work"
    _fake_data(work / "data", vehicles={f"vehicles/A/image{k}.png": _png(k) for k in range(3)})
    monkeypatch.chdir(work)
    assert len(load_dataset()) == 4
    # The argument beats the environment.
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "nowhere"))
    assert len(load_dataset(env_root)) == 2


def test_archives_are_closed_after_loading(tmp_path, monkeypatch):
    import zipfile

    from PIL import Image

    import vehicle_detection.training.data as data_module

    for cls in ("vehicles", "non-vehicles"):
        with zipfile.ZipFile(tmp_path / f"{cls}.zip", "w") as zf:
            for i in range(3):
                buf = io.BytesIO()
                Image.new("RGB", (64, 64), (i * 40, 0, 0)).save(buf, format="PNG")
                zf.writestr(f"{cls}/src/{i}.png", buf.getvalue())
    opened = []

    class Recording(zipfile.ZipFile):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            opened.append(self)

    monkeypatch.setattr(data_module.zipfile, "ZipFile", Recording)
    ds = load_dataset(tmp_path)
    assert len(ds) == 6 and len(opened) == 2
    assert all(zf.fp is None for zf in opened)  # closed
