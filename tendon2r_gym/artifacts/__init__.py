"""Artifacts: what training leaves on disk and the library reads back.  The run folders
(runs), the model files (files: the SB3 zip and its VecNormalize statistics, read without
unpickling), the bundles of shipped models (bundle), the registry of shipped models
(registry) and the checks that a model meets the env it runs on (model_env)."""
