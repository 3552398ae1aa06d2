"""The run folder: the one package that names, writes and reads what a run leaves behind.

A run folder is the only thing a run leaves behind and the only thing the dashboard reads, so
its format is owned here once and every writer and reader (training, evaluation, tables,
`detach-run list`, the dashboard) goes through these modules; tests/test_architecture.py checks
that no other module writes a path to one of its files. It imports only the configuration
layer, the standard library and mcap (never torch): any layer above may use it.
docs/ARCHITECTURE.md ("Run folder") describes it in prose.

    runs/<YYYYmmdd-HHMMSS>-<task>-<model>-s<seed>/
        config.yaml          fully resolved RunConfig (reloads identically)
        status.json          `messages.Status`, with the run's `RunSummary` (task, model, seed,
                             samples per iteration; `summary` reads config.yaml without one)
        stdout.log           everything the run printed
        log.mcap             /metrics `MetricsMessage` per iteration, /scene `SceneMessage`,
                             /episode/bodies `EpisodeFrame` per recorded frame (`mcap_writer`,
                             `mcap_reader`, `log_tail`); for Foxglove /tf, /foxglove/scene and
                             /foxglove/task (`detach.runs.mcap_log`)
        checkpoints/model_<iteration>.pt
        checkpoints/amp_replay_<iteration>.pt   AMP replay buffer of the newest checkpoint
        selection.json       with train.select_checkpoint_trials: each checkpoint's validation
                             score and the one chosen as the run's policy (`checkpoints`)
        eval.json            `eval_result.EvalResult` on the run's own task; eval_<task>.json on another
        provenance.json      code and machine of the run (one record per start / resume)
        params/agent.yaml    rsl-rl's train config (OnPolicyRunner(env, it).load(checkpoint))
        events.out.tfevents.*, wandb/   with train.logger tensorboard / wandb
        exported/policy_<iteration>.onnx | .pt (+ .json: input layout)   `detach-run export`

Modules: `names`, `messages`, `eval_result`, `atomic`, `files`, `folder`, `liveness`,
`checkpoints`, `summary`, `mcap_writer`, `mcap_reader`, `log_tail`.
"""
