"""The whole Blender workflow in a real, windowed Blender, driven through the add-on's operators and
panels as a user drives them (scripts/gui_workflow_blender.py inside Blender, started by
scripts/gui_workflow.py under Xvfb).

Import Capture -> Estimate Poses (the Capture panel's status lines, then its Details sub-panel opened)
-> Reconstruct with VoRTX (the panel's voxel size and views per tile, tiles shown while it runs; then
Esc, which must leave the scene unchanged: the network takes many minutes per tile on a loaded CPU) ->
Reconstruct with Stereo, the default, at the Preview quality chosen in the panel -> Show Observation ->
Bake Texture -> Export Result (GLB) -> the closed sub-panels opened and the sidebar scrolled to its last
panels. The panels stay as a new user finds them (sub-panels closed by default stay closed) until the
last step, so the first screenshots show what fits on the screen. The long jobs are invoked as the panel's buttons invoke them ('INVOKE_DEFAULT': modal, with
progress in the status bar and the sidebar), so the window keeps drawing while they run. After each
step the scene is checked; screenshots of the VoRTX sidebar and of the whole window are taken with
ImageMagick's `import` (Blender's own screenshot operator gives black images with software GL).

Everything happens in timer callbacks: a --python script runs before the window's first draw, and
modal operators need the event loop running. The outcome is written to <out>/report.json (steps,
checks, timings, screenshots); Blender then quits. A failed check ends the run there.

report.py keeps the report, x11.py builds the X commands (screenshots, clicks), panels.py the panel
classes that show sub-panels open; window.py and steps.py run inside Blender. phone.py is the
phone-capture variant (scripts/gui_workflow.py --phone-export): Import Capture on a phone app's export,
Reconstruct, the README's docs/gui_phone_* screenshots.
"""
