"""`make demo` (scripts/demo.py): the whole product on the bundled sample capture, checked against
the sample's truth.

1. Runs scripts/vortx_batch.py on the sample's photos only (samples/demo_room/images): Import
   Capture, Estimate Poses (structure from motion, gravity, scale from the floor and the 1.5 m
   camera height), Reconstruct with the default method -> out/demo.blend and out/demo.ply.
2. Pose error: the estimated cameras (read back from out/demo.blend) against truth/pose, after the
   similarity (Sim(3)) that best maps the estimated camera centres onto the true ones; SfM knows
   the world only up to such a transform (engine/eval/against_truth.py).
3. out/demo.png: a capture photo beside a Workbench render (vertex colours) of the mesh from that
   photo's estimated camera, at the photo's resolution.
4. The other method (`engine reconstruct`) on the same estimated poses (out/demo_posed), unless
   --no-compare.
5. F-scores against truth/mesh_gt.ply, side by side with a plain room box: each mesh is moved into
   the truth frame with the same Sim(3) first, then scored with the Atlas metrics (5 cm threshold),
   trimmed to the space the truth TSDF observed, and with the surface metrics
   (engine/eval/surface_metrics.py: normal agreement, floater share, pieces, area ratio, open
   boundary per m^2).
6. The textured result: `engine texture` on the estimated poses -> out/demo.glb (VR preset, 4096 px);
   out/demo_glb.png: the photo of step 3 beside demo.glb imported with Blender's own glTF importer
   and rendered with Cycles from the same camera.
7. How it looks from photos it was not made from: HELDOUT_PHOTOS photos spread over the walk are held
   out, the texture (HELDOUT_TEXTURE_SIZE px), the vertex colours and the true mesh (moved into the
   estimated frame by the inverse Sim(3)) are made from the others, rendered from the held-out
   cameras and compared with the photos (PSNR, SSIM) -> a table and out/demo_texture.png.

pipeline.py runs these steps; blender_views.py reads the .blend and renders in Blender; pictures.py
puts a photo beside a render; heldout.py is step 7.
"""
