"""Integrations with third-party RL frameworks, imported on demand (never by ``import covert_env``).

* :mod:`covert_env.integrations.benchmarl`: the BenchMARL task (``pip install "covert_env[benchmarl]"``).
* :mod:`covert_env.integrations.torchrl`: a TorchRL ``EnvBase`` on the vector env, B copies in one process
  (``pip install "covert_env[torchrl]"``).

TorchRL, Tianshou, Stable-Baselines3 and RLlib need no adapter of ours: the README section
"Use it with your framework" shows each of them on the environments as they are.
"""
