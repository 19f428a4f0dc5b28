"""Matched scenario panels: a manifest crossed with a stressor grid (`grid`), the contract
check that refuses comparing unlike panels (`contract`), the contact sheet and panel video
(`sheet`), the success detector on frames (`detect`) and the world-model plug point (`world`).
Pure: no Prefect, no warehouse."""
