"""Developer tooling run from a checkout: the demo (`make demo`) and the real-window GUI workflow
(README screenshots). Never shipped in the extension (blender_manifest.toml excludes /devtools/);
it may import the engine, never the other way round."""
