"""The run loop: a run directory's session from start to finish, its records, logs and
progress, several processes, and the start-up machinery (ahead-of-time compilation,
the persistent compilation cache). Imports ``train.learner`` and below."""
