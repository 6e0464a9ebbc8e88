"""Reading ROS map_server maps (world/occupancy.py): the pixel rules of nav2's
loadMapFromFile, row order, origin, image formats, and one-line errors naming file and field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from polyslam_env.core.errors import MapFileError
from polyslam_env.world.occupancy import FREE, OCCUPIED, UNKNOWN, read_map_yaml

YAML = """image: {image}
resolution: {resolution}
origin: {origin}
occupied_thresh: 0.65
free_thresh: 0.196
negate: {negate}
{extra}"""


def write_pgm(path: Path, pixels: np.ndarray, plain: bool = False, maxval: int = 255) -> Path:
    """A PGM (P5 binary, or P2 plain) of ``pixels`` (H, W), first row on top."""
    h, w = pixels.shape
    header = f"{'P2' if plain else 'P5'}\n# a comment\n{w} {h}\n{maxval}\n".encode()
    if plain:
        body = "\n".join(" ".join(str(int(v)) for v in row) for row in pixels).encode()
    elif maxval > 255:
        body = pixels.astype(">u2").tobytes()
    else:
        body = pixels.astype(np.uint8).tobytes()
    path.write_bytes(header + body)
    return path


def write_map(
    folder: Path,
    pixels: np.ndarray,
    *,
    name: str = "map",
    resolution: float = 0.05,
    origin: str = "[0.0, 0.0, 0.0]",
    negate: int = 0,
    extra: str = "",
    plain: bool = False,
) -> Path:
    """A map_server YAML and its PGM in ``folder``; the YAML's path."""
    write_pgm(folder / f"{name}.pgm", pixels, plain=plain)
    text = YAML.format(image=f"{name}.pgm", resolution=resolution, origin=origin,
                       negate=negate, extra=extra)  # fmt: skip
    path = folder / f"{name}.yaml"
    path.write_text(text)
    return path


# Pixel values around the thresholds (occupancy p = 1 − v/255): 0 → 1.0, 89 → 0.651,
# 90 → 0.647, 204 → 0.2, 205 → 0.196 (p is 0.19608 > 0.196: unknown), 206 → 0.192, 254, 255.
VALUES = np.array([[0, 89, 90, 204], [205, 206, 254, 255]])
TRINARY = np.array([[OCCUPIED, OCCUPIED, UNKNOWN, UNKNOWN], [UNKNOWN, FREE, FREE, FREE]])


def test_read_map_yaml__trinary_thresholds_strict_as_map_server(tmp_path: Path) -> None:
    grid = read_map_yaml(write_map(tmp_path, VALUES))
    assert np.array_equal(grid.cells, TRINARY[::-1])  # rows bottom-up


def test_read_map_yaml__negate_swaps_black_and_white(tmp_path: Path) -> None:
    grid = read_map_yaml(write_map(tmp_path, 255 - VALUES, negate=1))
    assert np.array_equal(grid.cells, TRINARY[::-1])


def test_read_map_yaml__plain_pgm_and_16_bit_read_alike(tmp_path: Path) -> None:
    plain = read_map_yaml(write_map(tmp_path, VALUES, name="plain", plain=True))
    assert np.array_equal(plain.cells, TRINARY[::-1])
    write_pgm(tmp_path / "deep.pgm", VALUES * 257, maxval=65535)
    (tmp_path / "deep.yaml").write_text(
        YAML.format(image="deep.pgm", resolution=0.05, origin="[0, 0, 0]", negate=0, extra="")
    )
    assert np.array_equal(read_map_yaml(tmp_path / "deep.yaml").cells, TRINARY[::-1])


def test_read_map_yaml__png_with_alpha_averages_alpha_in_trinary(tmp_path: Path) -> None:
    """map_server averages an alpha channel (1 = opaque) with the colour in trinary mode: an
    opaque grey of 205 (unknown in a PGM) reads (3·205/255 + 1)/4 = 0.853, free."""
    from matplotlib import image as mpimg

    rgba = np.zeros((2, 4, 4))
    rgba[..., :3] = (VALUES / 255.0)[..., None]
    rgba[..., 3] = 1.0
    mpimg.imsave(tmp_path / "map.png", rgba)
    (tmp_path / "map.yaml").write_text(
        YAML.format(image="map.png", resolution=0.05, origin="[0, 0, 0]", negate=0, extra="")
    )
    shade = (3 * VALUES / 255.0 + 1.0) / 4
    p = 1.0 - shade
    expected = np.where(p > 0.65, OCCUPIED, np.where(p < 0.196, FREE, UNKNOWN))
    assert np.array_equal(read_map_yaml(tmp_path / "map.yaml").cells, expected[::-1])
    (tmp_path / "scale.yaml").write_text(
        YAML.format(
            image="map.png", resolution=0.05, origin="[0, 0, 0]", negate=0, extra="mode: scale"
        )
    )
    scale = read_map_yaml(tmp_path / "scale.yaml").cells  # no alpha in the mean; partial = wall
    assert np.array_equal(scale, np.where(TRINARY == UNKNOWN, OCCUPIED, TRINARY)[::-1])


def test_read_map_yaml__origin_places_the_lower_left_corner_and_yaw_turns(tmp_path: Path) -> None:
    pixels = np.full((3, 4), 0)
    pixels[0, 3] = 254  # top right pixel free
    grid = read_map_yaml(write_map(tmp_path, pixels, resolution=0.5, origin="[1.0, 2.0, 0.0]"))
    rows, cols = np.nonzero(grid.free)
    assert (rows.tolist(), cols.tolist()) == ([2], [3])
    centre = grid.to_world(np.array([(cols[0] + 0.5) * 0.5, (rows[0] + 0.5) * 0.5]))
    assert centre == pytest.approx([1.0 + 1.75, 2.0 + 1.25])
    turned = read_map_yaml(write_map(tmp_path, pixels, resolution=0.5,
                                     origin=f"[1.0, 2.0, {np.pi / 2}]"))  # fmt: skip
    assert turned.to_world(np.array([1.75, 1.25])) == pytest.approx([1.0 - 1.25, 2.0 + 1.75])


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.2\nnegate: 0\n",
         "occupied_thresh: missing"),
        ("image: map.pgm\nresolution: -1\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
         "free_thresh: 0.2\nnegate: 0\n", "resolution: must be > 0"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0]\noccupied_thresh: 0.65\n"
         "free_thresh: 0.2\nnegate: 0\n", r"origin: expected \[x, y, yaw\]"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
         "free_thresh: 0.8\nnegate: 0\n", "free_thresh: must not exceed occupied_thresh"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
         "free_thresh: 0.2\nnegate: 2\n", "negate: expected 0 or 1"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
         "free_thresh: 0.2\nnegate: 0\nmode: fancy\n", "mode: expected one of"),
        ("image: nothere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
         "free_thresh: 0.2\nnegate: 0\n", "image: .*nothere.pgm: no such file"),
        ("image: [unclosed\n", "not valid YAML"),
        ("- a list\n", "expected a mapping"),
    ],
)  # fmt: skip
def test_read_map_yaml__bad_file_one_line_error_naming_file_and_field(
    tmp_path: Path, text: str, field: str
) -> None:
    write_pgm(tmp_path / "map.pgm", VALUES)
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(MapFileError, match=field) as err:
        read_map_yaml(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_read_map_yaml__bad_images_one_line_errors(tmp_path: Path) -> None:
    yaml_text = YAML.format(image="map.pgm", resolution=0.05, origin="[0, 0, 0]", negate=0,
                            extra="")  # fmt: skip
    (tmp_path / "map.yaml").write_text(yaml_text)
    (tmp_path / "map.pgm").write_bytes(b"P5\n4 2\n255\n" + bytes(5))
    with pytest.raises(MapFileError, match=r"image: .*map.pgm: truncated: 5 of 4 × 2"):
        read_map_yaml(tmp_path / "map.yaml")
    (tmp_path / "map.pgm").write_bytes(b"GIF89a not a pgm")
    with pytest.raises(MapFileError, match="not a PGM image"):
        read_map_yaml(tmp_path / "map.yaml")
    (tmp_path / "map.yaml").write_text(yaml_text.replace("map.pgm", "map.png"))
    (tmp_path / "map.png").write_bytes(b"not a png at all")
    with pytest.raises(MapFileError, match="cannot read the image") as err:
        read_map_yaml(tmp_path / "map.yaml")
    assert "\n" not in str(err.value)
