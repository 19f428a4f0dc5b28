"""Policies that drive the simulator in place of the scripted controller.

`base`: the `Policy` interface (a controller factory for `tasks.sim.episode.rollout`) and
`ScriptedPolicy(noise)`; `features`: the privileged state a learned policy sees; `bc`: a
behaviour-cloning MLP trained on scripted episodes (collect, train, save, load). Pure: no
Prefect, no warehouse.
"""
