"""Real and broken meshes: scans that are not watertight load with one warning, the units
guess is reported, and every mesh error is one line naming the file, what is wrong and the
CLI flag to use."""

import numpy as np
import pytest

from sern_jax.commands import grasp_learn as learn_cli
from sern_jax.commands import main as cli
from sern_jax.grasp.world import objects

_PYTHON_ARGS = ("units=", "require_watertight", "max_vertices=")


def _cube(edge: float):
    """Vertices [8, 3] and the 12 outward triangles of a cube centred at 0."""
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    faces = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return v * edge / 2, np.array(faces)


def _write_obj(path, verts, faces):
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def _one_line(msg: str) -> str:
    assert "\n" not in msg, msg
    for arg in _PYTHON_ARGS:
        assert arg not in msg, msg
    return msg


def test_open_mesh_loads_with_one_warning_line(tmp_path, capsys):
    verts, faces = _cube(0.05)
    path = _write_obj(tmp_path / "scan.obj", verts, faces[2:])  # one square face missing
    spec = objects.load_mesh(path, units="m")
    np.testing.assert_allclose(spec.extents, (0.05, 0.05, 0.05), atol=1e-6)
    np.testing.assert_allclose(spec.volume, 0.05**3, rtol=1e-6)  # the convex hull
    np.testing.assert_allclose(spec.mass, 400.0 * 0.05**3, rtol=1e-6)
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    line = _one_line(lines[0])
    assert "scan.obj" in line and "not watertight" in line
    assert "convex hull" in line and "estimated from the hull volume" in line
    assert "50 g" in line  # 125 cm^3 at 400 kg/m^3
    # Warned once: the same mesh again (and through resolve_object) says nothing more.
    assert objects.resolve_object(str(path), units="m") == spec
    assert capsys.readouterr().err == ""
    # The watertight cube says nothing; the strict mode still refuses the open one.
    objects.load_mesh(_write_obj(tmp_path / "closed.obj", verts, faces), units="m")
    assert capsys.readouterr().err == ""
    with pytest.raises(ValueError, match="not watertight"):
        objects.load_mesh(path, units="m", require_watertight=True)


def test_open_mesh_with_given_mass_says_so(tmp_path):
    verts, faces = _cube(0.04)
    path = _write_obj(tmp_path / "cup.obj", verts, faces[:-2])
    lines = []
    spec = objects.load_mesh(path, units="m", mass=0.3, log=lines.append)
    assert spec.mass == 0.3
    assert len(lines) == 1 and "300 g as given" in lines[0]


def test_random_bytes_stl_is_not_a_readable_mesh(tmp_path):
    path = tmp_path / "noise.stl"
    path.write_bytes(np.random.default_rng(0).bytes(3000))
    with pytest.raises(ValueError) as exc:
        objects.load_mesh(path)
    msg = _one_line(str(exc.value))
    assert str(path) in msg and "not a readable mesh" in msg
    assert "charset" not in msg and "module" not in msg.lower()


@pytest.mark.parametrize("edge, shown", [(1e30, "1e+30"), (1e-9, "1e-09")])
def test_absurd_coordinates_name_the_size_and_the_flag(tmp_path, edge, shown):
    path = _write_obj(tmp_path / "odd.obj", *_cube(edge))
    with pytest.raises(ValueError) as exc:
        objects.load_mesh(path)
    msg = _one_line(str(exc.value))
    assert str(path) in msg and "absurd size" in msg and shown in msg
    assert "--mesh-units" in msg and "empty" not in msg
    # With explicit units the size in metres and the flag's value are named.
    with pytest.raises(ValueError) as exc:
        objects.load_mesh(path, units="mm")
    msg = _one_line(str(exc.value))
    assert "--mesh-units mm" in msg and f"{edge * 1e-3:.3g} m" in msg


def test_auto_units_report_the_guess_and_size(tmp_path, capsys):
    path = _write_obj(tmp_path / "mug.obj", *_cube(6.0))  # a 6 cm cube written in cm
    spec = objects.load_mesh(path)
    np.testing.assert_allclose(spec.extents, (0.06, 0.06, 0.06), atol=1e-6)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1, lines
    line = _one_line(lines[0])
    assert "mug.obj" in line and "--mesh-units auto" in line
    assert "as cm" in line and "6 x 6 x 6 cm" in line
    # Explicit units print nothing.
    objects.load_mesh(path, units="cm")
    assert capsys.readouterr().err == ""


def test_bad_units_name_the_flag(tmp_path):
    path = _write_obj(tmp_path / "box.obj", *_cube(0.05))
    with pytest.raises(ValueError, match="--mesh-units") as exc:
        objects.load_mesh(path, units="inch")
    _one_line(str(exc.value))


def test_learn_and_screen_take_mesh_units(tmp_path, capsys):
    parser = cli.build_parser()
    path = str(_write_obj(tmp_path / "block.obj", *_cube(60.0)))  # 6 cm in mm
    for command in ("learn", "screen"):
        args = parser.parse_args(["grasp", command, "--mesh", path, "--mesh-units", "mm"])
        assert args.mesh_units == "mm"
    spec, = learn_cli._specs([], [path], (), "mm")
    np.testing.assert_allclose(spec.extents, (0.06, 0.06, 0.06), atol=1e-6)
    # A path given as an object name gets the units too: 60 cm is too large.
    with pytest.raises(ValueError, match="0.6 m read with --mesh-units cm"):
        learn_cli._specs([path], [], (), "cm")
    assert capsys.readouterr().err == ""


def test_cli_mesh_errors_are_one_line(tmp_path, capsys):
    noise = tmp_path / "noise.stl"
    noise.write_bytes(np.random.default_rng(1).bytes(2000))
    big = _write_obj(tmp_path / "big.obj", *_cube(1e30))
    out = tmp_path / "out"
    for argv in (["grasp", "show", "--mesh", str(noise), "--out", str(out)],
                 ["grasp", "show", "--mesh", str(big), "--out", str(out)],
                 ["grasp", "learn", "--mesh", str(big), "--out", str(out)]):
        assert cli.main(argv) == 2
        cap = capsys.readouterr()
        lines = cap.err.splitlines()
        assert len(lines) == 1, cap.err
        line = _one_line(lines[0])
        assert line.startswith("sern: error: mesh ") and "Traceback" not in cap.err
        assert ("not a readable mesh" in line) if argv[3] == str(noise) else (
            "--mesh-units" in line)
    assert not out.exists()
