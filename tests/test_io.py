"""sern_jax.io: atomic writes keep the usual file mode."""

import os
import stat

from sern_jax import io


def test_files_get_the_umask_mode_not_0600(tmp_path):
    old = os.umask(0o022)
    try:
        io.save_json(tmp_path / "a.json", {"x": 1})
        io.save_npz(tmp_path / "b.npz", x=[1, 2])
        io.save_text(tmp_path / "c.md", "hi")
        os.umask(0o077)
        io.save_text(tmp_path / "d.md", "private")
    finally:
        os.umask(old)
    for name in ("a.json", "b.npz", "c.md"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name
    assert stat.S_IMODE((tmp_path / "d.md").stat().st_mode) == 0o600
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
