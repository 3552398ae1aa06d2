"""Run `detach-run` with PPO's per-minibatch KL recorded: one `KLPROBE {json}` line per update
on stdout (the KL of each minibatch against the policy that collected the batch; the first
minibatch comes before any gradient step, so a non-zero first value would mean the update
sees a different policy than the rollout did).

    python results/laptop/diagnosis/kl_probe.py train climb --model mlp env.character=puppet ... > c4.log
    grep -o 'KLPROBE {.*' c4.log > kl.jsonl
"""
import json
import sys

from rsl_rl.algorithms.ppo import PPO
from rsl_rl.models.mlp_model import MLPModel

from detach import cli_main

_current: dict = {}
_kl = MLPModel.get_kl_divergence
_update = PPO.update


def _recording_kl(self, old, new):
    kl = _kl(self, old, new)
    _current["kls"].append(float(kl.mean()))
    return kl


def _recording_update(self):
    _current.clear()
    _current["kls"] = []
    out = _update(self)
    print("KLPROBE", json.dumps({"kls": [round(k, 5) for k in _current["kls"]], "lr": self.learning_rate}),
          flush=True)
    return out


MLPModel.get_kl_divergence = _recording_kl
PPO.update = _recording_update
sys.exit(cli_main(sys.argv[1:]))
