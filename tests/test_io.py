"""Image and frame files: exact round trips through OpenImageIO and the packed .npz format."""

import numpy as np
import pytest

from spc3d import io
from spc3d.physics import spc


@pytest.mark.parametrize("bits,tol", [(8, 0.5 / 255), (16, 0.5 / 65535)])
def test_png_round_trip(tmp_path, bits, tol):
    img = np.random.default_rng(0).random((7, 11, 3)).astype(np.float32)
    io.write_image(tmp_path / "a.png", img, bits=bits)
    back = io.read_image(tmp_path / "a.png")
    assert back.shape == (7, 11, 3)
    assert np.abs(back - img).max() <= tol + 1e-7


def test_exr_float32_exact(tmp_path):
    depth = np.random.default_rng(1).uniform(0.1, 1e4, (5, 9, 1)).astype(np.float32)
    io.write_image(tmp_path / "d.exr", depth)
    back = io.read_image(tmp_path / "d.exr")
    assert back.dtype == np.float32 and np.array_equal(back, depth)


def test_two_dimensional_input_is_written_as_one_channel(tmp_path):
    gray = np.linspace(0, 1, 20, dtype=np.float32).reshape(4, 5)
    io.write_image(tmp_path / "g.png", gray)
    back = io.read_image(tmp_path / "g.png")
    assert back.shape == (4, 5, 1)
    np.testing.assert_allclose(back[:, :, 0], gray, atol=0.5 / 255 + 1e-7)
    assert io.read_rgb(tmp_path / "g.png").shape == (4, 5, 3)


def test_one_bit_tiff_round_trip(tmp_path):
    bits = np.random.default_rng(2).random((13, 17, 3)) < 0.3
    io.write_image(tmp_path / "b.tif", bits.astype(np.float32), bits=1)
    back = io.read_image(tmp_path / "b.tif")
    assert np.array_equal(back > 0.5, bits)


def test_one_bit_needs_tiff(tmp_path):
    with pytest.raises(ValueError, match="tif"):
        io.write_image(tmp_path / "b.png", np.zeros((2, 2, 3)), bits=1)


def test_packed_frames_round_trip(tmp_path):
    frames = np.random.default_rng(3).random((3, 5, 7, 3)) < 0.5
    io.save_frames(tmp_path / "f.npz", *spc.pack_frames(frames))
    packed, shape = io.load_frames(tmp_path / "f.npz")
    assert np.array_equal(spc.unpack_frames(packed, shape), frames)
    assert packed.nbytes == int(np.ceil(frames.size / 8))


def test_unreadable_files_name_the_path(tmp_path):
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(ValueError, match="broken.png"):
        io.read_image(bad)
    with pytest.raises(ValueError, match="broken.png"):
        io.load_frames(bad)
    with pytest.raises(FileNotFoundError, match="nothing"):
        io.list_images(tmp_path / "nothing")


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "x.json"
    io.write_json(target, {"v": 1})
    with pytest.raises(RuntimeError):
        with io.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert io.read_json(target) == {"v": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]  # no temporary left behind


def test_atomic_directory_replaces_whole(tmp_path):
    out = tmp_path / "dir"
    with io.atomic_path(out, is_dir=True) as tmp:
        (tmp / "a.txt").write_text("1")
    with io.atomic_path(out, is_dir=True) as tmp:
        (tmp / "b.txt").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == ["b.txt"]


def test_atomic_folders_follow_the_umask_and_stale_temporaries_go(tmp_path):
    """A finished folder has the umask's permissions (mkdtemp alone would leave it 0700); the
    temporary siblings an interrupted writer left are removed when the same path is written again."""
    stale = tmp_path / ".out.abcd1234.tmp"
    (stale / "half").mkdir(parents=True)
    (tmp_path / ".out.json.wxyz6789.tmp").write_text("half")  # another output's leftover: not ours to remove
    with io.atomic_path(tmp_path / "out", is_dir=True) as tmp:
        (tmp / "x.txt").write_text("1")
    assert (tmp_path / "out" / "x.txt").read_text() == "1"
    assert (tmp_path / "out").stat().st_mode & 0o777 == 0o777 & ~io.UMASK
    assert not stale.exists() and (tmp_path / ".out.json.wxyz6789.tmp").exists()


def test_image_shape_reads_only_the_header(tmp_path):
    io.write_image(tmp_path / "a.png", np.zeros((5, 7, 3), np.float32))
    assert io.image_shape(tmp_path / "a.png") == (5, 7, 3)
    (tmp_path / "b.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="b.png"):
        io.image_shape(tmp_path / "b.png")


def test_load_torch_never_runs_pickled_code(tmp_path):
    import torch

    class Evil:
        def __reduce__(self):
            return (exec, ("raise SystemExit('ran')",))

    torch.save({"w": Evil()}, tmp_path / "evil.pt")
    with pytest.raises(ValueError, match=r"evil\.pt is not a readable weights file \(it holds pickled"):
        io.load_torch(tmp_path / "evil.pt", "weights file")
    torch.save({"w": torch.ones(2)}, tmp_path / "ok.pt")
    assert torch.equal(io.load_torch(tmp_path / "ok.pt")["w"], torch.ones(2))
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        io.load_torch(tmp_path / "missing.pt")
