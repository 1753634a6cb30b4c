"""The batch of scripts/vortx_batch.py without Blender: its command line, the output plan of each
capture, the JSON report, the loop over captures and the Ray cluster driver.

What runs inside Blender (the extension's operators on one capture) is vortx_blender/batch.py.
"""
