"""Fitting a field module with Lightning: checkpoints and exact resume, Ctrl-C / SIGTERM as a clean interruption,
no partial result ever returned as complete."""

from __future__ import annotations

import contextlib
import logging
import signal

from qmdf.errors import Interrupted, QmdfError


def fit(
    module,
    steps: int,
    *,
    work_dir,
    seed: int,
    log,
    logger=None,
    checkpoint_every: int = 250,
    resume: bool = True,
    accelerator: str = "auto",
    show_progress: bool = False,
    on_end=None,
) -> str:
    """Train ``module`` for ``steps`` with Lightning in ``work_dir`` (checkpoints, resume); returns the device it
    ran on. A training that ends short of ``steps`` is an error, never a result (a cache would keep it as
    complete). Ctrl-C or SIGTERM save a checkpoint and raise ``Interrupted``; ``on_end`` runs after the loggers
    are finalised (wandb's one run per job)."""
    import gc
    import warnings

    import lightning as L
    import torch

    from qmdf.fields.data import loader
    from qmdf.fields.module import LOG_EVERY, Diverged

    L.seed_everything(seed, workers=True, verbose=False)
    warnings.filterwarnings("ignore", message=".*LeafSpec.*")  # Lightning's own deprecation noise, not ours
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    last = work_dir / "last.ckpt"
    resume_from = str(last) if resume and last.exists() else None
    done = int(torch.load(last, map_location="cpu", weights_only=True)["global_step"]) if resume_from else 0
    checkpoint = L.pytorch.callbacks.ModelCheckpoint(
        dirpath=work_dir, save_last=True, save_top_k=0, every_n_train_steps=checkpoint_every
    )

    stop = _StopSignal()

    class StopAtStepEnd(L.pytorch.callbacks.Callback):
        """A signal only marks the stop: the step under way finishes, that state is saved, and training stops.
        A checkpoint written where the signal struck (weights stepped, step count not yet) resumed into another
        field (bench faults: 1 trial of 9, weights 8e-2 apart)."""

        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            if stop.received:
                trainer.save_checkpoint(last)
                trainer.should_stop = True

    callbacks = [checkpoint, StopAtStepEnd()]
    if not show_progress:  # a log or a pipe gets a line now and then instead of a bar, so it never looks hung
        callbacks.append(_heartbeat(L, log, steps))
    trainer = L.Trainer(
        max_steps=steps,
        max_epochs=1,
        accelerator=accelerator,
        devices=1,
        logger=logger if logger is not None else False,
        callbacks=callbacks,
        enable_progress_bar=show_progress,
        enable_model_summary=False,
        log_every_n_steps=LOG_EVERY,
        num_sanity_val_steps=0,
        limit_val_batches=0,
        default_root_dir=str(work_dir),
    )
    if resume_from:
        log.info("resuming from %s (step %d of %d)", last, done, steps)
    try:
        with stop.terminate_as_interrupt():
            trainer.fit(module, train_dataloaders=loader(steps), ckpt_path=resume_from)
        if trainer.global_step != steps and not stop.received:
            raise QmdfError(f"training stopped at step {trainer.global_step} of {steps}; its result is not kept")
    except (KeyboardInterrupt, SystemExit) as exc:
        # a second signal, or Ctrl-C outside the main thread: stopped at once, the last periodic checkpoint stays
        # (Lightning turns KeyboardInterrupt into SystemExit(1))
        if not (stop.received or isinstance(exc, KeyboardInterrupt)):
            raise
        stop.received = stop.received or signal.SIGINT
    except Diverged as exc:
        keep = f"; the last good checkpoint is {last}" if last.exists() else ""
        raise QmdfError(f"training diverged: {exc}{keep}. Lower train.optim.lr or check the input") from None
    finally:
        for lg in trainer.loggers:
            lg.finalize("success")
        if on_end is not None:
            on_end()
        # Nothing of Lightning may outlive the call: its loggers would flush into this scratch folder
        # after the pipeline moved it into place.
        device = str(trainer.strategy.root_device)
        at = trainer.global_step
        del trainer
        gc.collect()
    if stop.received:
        raise Interrupted(
            f"{signal.Signals(stop.received).name} at training step {at} of {steps}: checkpoint saved at "
            f"{last}; run the same command again to resume",
            int(stop.received),
        )
    return device


def _heartbeat(L, log, steps: int):
    """A Lightning callback: the step, the loss and the time left in the log, at most every 15 s."""
    from qmdf.progress import Heartbeat

    class LogHeartbeat(L.pytorch.callbacks.Callback):
        def __init__(self):
            self.heart = Heartbeat(log, "train: step", steps)

        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            loss = outputs["loss"] if isinstance(outputs, dict) else outputs
            self.heart.beat(trainer.global_step, f"loss {float(loss):.4g}")

    return LogHeartbeat()


class _StopSignal:
    """Ctrl-C (SIGINT) and SIGTERM (what a cluster scheduler sends) end a training the same way: the step under
    way finishes, ``StopAtStepEnd`` writes the checkpoint and stops Lightning, and the run ends as interrupted with
    128 + the signal's number. A second signal stops at once."""

    def __init__(self):
        self.received = 0

    @contextlib.contextmanager
    def terminate_as_interrupt(self):
        def handler(signum, frame):
            if self.received:
                raise KeyboardInterrupt
            self.received = signum

        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            for s in old:
                signal.signal(s, handler)
        except ValueError:  # not the main thread (an API caller's worker): signals stay theirs
            old = {}
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)
