"""boxpose's Blender stage: builds a Blender scene from `scenes` / `objects` rows, renders it with
Cycles on the CPU and extracts per-frame ground truth as `frames` / `instances` rows.

Modules without bpy (importable anywhere): `geometry` (poses, pinhole camera, the one Blender ↔
OpenCV camera conversion), `recipe`, `sampling` (every random draw), `groundtruth`, `sensor`
(simulated structured-light depth), `exr`, `synthetic` (scene rows for tests without Drake).
With bpy: `scene` (the Blender scene), `session` (load once, render many), `worker` (renders a
shard of a dataset: `python -m blender_scripts.worker --help`).
"""

# Bumped whenever a change alters rendered images or ground truth; stored in render_settings.
VERSION = "1"
