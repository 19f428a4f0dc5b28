"""`worldline train-transfer` and `worldline transfer`: episodes in other looks (docs/transfer.md)."""

from __future__ import annotations

from flows import cli_checks as need
from flows.cli_command import command
from flows.cli_shell import app, out, refuse, writing
from flows.params_transfer import TrainTransferParams, TransferParams
from schemas.settings import Settings


@command(app, TrainTransferParams, "train-transfer")
def train_transfer(params: TrainTransferParams) -> None:
    """Train a transfer model on a manifest's simulator pairs: each seed in every look, the
    source look's controls against the look's frames (Prefect flow `train-transfer`)."""
    params.check_scenario(need.simulable(params.manifest))
    from flows.transfer import train_transfer as train_flow

    writing()
    try:
        result = train_flow(**params.model_dump())
    except (FileNotFoundError, ValueError) as exc:
        refuse(exc)
    done = (f"loss {result['final_loss']:.4f}, train PSNR {result['final_psnr']:.2f} dB" if result["trained"]
            else "trained before")
    out.print(f"transfer model {result['checkpoint_id']} ({done}) under {result['checkpoint']}", highlight=False)


@command(app, TransferParams)
def transfer(params: TransferParams) -> None:
    """Simulated episodes in other looks by a transfer model, from their controls, labels copied
    unchanged, under transfer/ (Prefect flow `transfer`); a bad look, model, camera or control
    is refused in one line before anything is written."""
    folder, _, _ = params.check_inputs(Settings().data_root)
    from flows.transfer import transfer as transfer_flow

    writing()
    try:
        result = transfer_flow(**params.model_copy(update={"model": str(folder)}).model_dump())
    except (FileNotFoundError, ValueError) as exc:
        refuse(exc)
    out.print(f"{result['episodes']} episodes x {len(result['looks'])} looks: {len(result['written'])} clips written, "
              f"{result['done_before']} done before", highlight=False)
