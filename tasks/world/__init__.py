"""World model stage: code sequences in, pre-trained and post-trained world models out, and
the physical checks of their rollouts.

Modules: `data` (token shards and simulated episodes as code sequences, actions aligned to
latent steps, an episode code cache), `train` (the pre- and post-training loops),
`checkpoints` (safetensors checkpoints and their lineage records), `geometry` (pinhole
geometry of MuJoCo cameras) and `physics` (physical consistency checks of rollouts).
The diffusion family beside it: `diffusion` (its training and checkpoints), `latents`
(continuous token shards and episodes as latent sequences, an episode latents cache) and
`family` (which family a checkpoint folder holds, and loading either).
"""
