"""What ``r2s view`` does: start the viewer, print its URL, serve (or take one screenshot)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from r2s.console import console
from r2s.viewer.server import serve_forever, start_viewer


def view_scene(scene_dir: Path, host: str = "127.0.0.1", port: int = 8080,
               screenshot: Optional[Path] = None) -> None:
    """Serve ``scene_dir`` until Ctrl-C; with ``screenshot``, save one picture and return."""
    app = start_viewer(Path(scene_dir), host=host, port=port,
                       progress=lambda m: console.print(f"[dim]{m}[/dim]"))
    moved = ", ".join(m.caption for m in app.playback.motions if m.moved) or "none"
    console.print(f"objects that moved in the {app.playback.times_s[-1]:.1f} s rollout: {moved}")
    if screenshot is not None:
        from r2s.viewer.browser import screenshot as take_screenshot

        try:
            take_screenshot(app.url, screenshot)
        finally:
            app.stop()
        console.print(f"screenshot: {screenshot}")
        return
    console.print(f"r2s view: open [bold]{app.url}[/bold]  (Ctrl-C to stop)")
    serve_forever(app)
