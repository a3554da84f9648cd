"""The engine's EXR writer (``core.file.exr``) against readers it does not share code with:
OpenEXR's own (the pip wheel) and Blender's; the textures Apply writes with it in its work
(``blender.material.write_texture``): sealed, verified, bounded, never written over."""

import os

import numpy as np
import pytest

from addon.core.file.exr import exr_bytes, write_exr
from addon.core.file.safeio import UnsafePath, check_image_header


def _read_openexr(path):
    import OpenEXR

    f = OpenEXR.File(str(path))
    header = f.header()
    assert header["compression"] == OpenEXR.NO_COMPRESSION
    assert header["type"] == OpenEXR.scanlineimage
    (rgba,) = f.channels().values()
    return rgba.pixels


@pytest.mark.parametrize("shape", [(1, 1, 3), (3, 18, 3), (7, 5, 4), (64, 128, 3)])
def test_openexr_reads_back_every_value(tmp_path, shape):
    rng = np.random.default_rng(sum(shape))
    a = (rng.standard_normal(shape) * 10.0 ** rng.integers(-6, 6, shape)).astype(np.float32)
    path = write_exr(a, str(tmp_path / "a.exr"))
    got = _read_openexr(path)
    assert got.dtype == np.float32 and got.shape == shape[:2] + (4,)
    assert np.array_equal(got[..., : shape[2]], a)  # exact: float32 in, float32 out
    if shape[2] == 3:
        assert np.all(got[..., 3] == 1.0)
    # the product's own header check agrees on the size (width, height)
    assert check_image_header(path) == (shape[1], shape[0])


def test_the_first_row_is_the_top(tmp_path):
    a = np.zeros((4, 2, 3), np.float32)
    a[0] = 1.0  # top row
    got = _read_openexr(write_exr(a, str(tmp_path / "top.exr")))
    # OpenEXR's first scanline is the image's top (y increases downward)
    assert np.all(got[0, :, :3] == 1.0) and np.all(got[1:, :, :3] == 0.0)


def test_bad_shapes_and_oversized_images_are_refused_before_any_write(tmp_path):
    from addon.core import limits

    for bad in (np.zeros((4, 4)), np.zeros((4, 4, 2)), np.zeros((0, 4, 3))):
        with pytest.raises(ValueError):
            exr_bytes(bad)
    huge = np.broadcast_to(np.zeros(3, np.float32), (limits.MAX_IMAGE_SIDE + 1, 1, 3))  # no memory taken
    with pytest.raises(ValueError, match="limit"):
        write_exr(huge, str(tmp_path / "huge.exr"))
    assert os.listdir(tmp_path) == []


def test_no_write_over_a_folder_or_an_input(tmp_path):
    (tmp_path / "dir.exr").mkdir()
    with pytest.raises(UnsafePath):
        write_exr(np.zeros((2, 2, 3), np.float32), str(tmp_path / "dir.exr"))
    src = tmp_path / "input.exr"
    src.write_bytes(b"not yet")
    with pytest.raises(UnsafePath):
        write_exr(np.zeros((2, 2, 3), np.float32), str(src), inputs=(str(src),))
    assert src.read_bytes() == b"not yet"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.exr", "input.exr"]  # no temporary left


@pytest.mark.blender
def test_blender_reads_the_same_pixels(fresh, tmp_path):
    bpy = fresh
    rng = np.random.default_rng(3)
    a = rng.random((6, 9, 3)).astype(np.float32) * 4.0
    img = bpy.data.images.load(write_exr(a, str(tmp_path / "b.exr")))
    img.colorspace_settings.name = "Non-Color"
    got = np.array(img.pixels[:], np.float32).reshape(6, 9, 4)[::-1]  # Blender's first row is the bottom
    assert (img.size[0], img.size[1]) == (9, 6)
    assert np.array_equal(got[..., :3], a)


@pytest.mark.blender
def test_apply_textures_are_sealed_reused_renamed_when_damaged_and_bounded(fresh, tmp_path, monkeypatch):
    from addon.blender import material as artist
    from addon.core import limits

    monkeypatch.setattr(limits, "ARTIST_TEXTURE_MAX_ENTRIES", 3)
    folder = str(tmp_path / "artist")
    place = (folder, False, ())
    px = [np.full((3, 18, 3), i, np.float32) for i in range(6)]
    first = artist.write_texture(place, "brdfm-lookup", px[0])
    assert os.path.isfile(first + ".seal")
    assert np.all(_read_openexr(first)[..., :3] == 0.0)
    assert artist.write_texture(place, "brdfm-lookup", px[0]) == first  # verified: reused
    with open(first, "r+b") as fh:  # damaged: a new file under a new name, the damaged one left
        fh.seek(os.path.getsize(first) - 4)
        fh.write(b"\xff\xff\xff\xff")
    second = artist.write_texture(place, "brdfm-lookup", px[0])
    assert second != first and np.all(_read_openexr(second)[..., :3] == 0.0)
    # bounded: the least recently used go, never a file still in use nor one the product did
    # not seal
    foreign = os.path.join(folder, "brdfm-lookup-mine.exr")
    with open(foreign, "wb") as fh:
        fh.write(b"the artist's own")
    made = [artist.write_texture((folder, False, (second,)), "brdfm-lookup", p) for p in px[1:]]
    left = set(os.listdir(folder))
    assert os.path.basename(second) in left  # in use
    assert os.path.basename(foreign) in left
    assert {os.path.basename(m) for m in made[-2:]} <= left
    assert os.path.basename(made[0]) not in left
    sealed = [n for n in left if n.endswith(".exr") and n + ".seal" in left]
    assert len(sealed) <= 3 + 1  # the bound, and the one in use


@pytest.mark.blender
def test_beside_the_blend_a_texture_is_written_once_under_its_content_name(fresh, tmp_path):
    from addon.blender import material as artist

    place = (str(tmp_path / "brdf_moments"), True, ())
    px = np.full((3, 18, 3), 0.25, np.float32)
    path = artist.write_texture(place, "brdfm-lookup", px)
    assert artist.write_texture(place, "brdfm-lookup", px) == path
    assert os.listdir(tmp_path / "brdf_moments") == [os.path.basename(path)]  # no seal in the artist's folder
    assert np.all(_read_openexr(path)[..., :3] == 0.25)
