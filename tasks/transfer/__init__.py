"""The transfer step (docs/transfer.md, issue 32): simulator pairs of a source look's controls and
another look's frames (`pairs`), the transfer model's training loop and checkpoints (`train`),
running a trained model on simulated episodes (`apply`) and the lineage of both (`lineage`);
its smoke run is `bench/transfer_smoke.py`. The model itself is `models/transfer.py`."""
