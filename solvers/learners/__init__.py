"""Multi-agent learners: ``nashq`` and ``iql`` (their engine :mod:`fixbench.solvers.learners.marl_engine`),
``vdn``, and ``mappo``, ``ippo`` and ``qmix`` from TorchRL's components
(:mod:`fixbench.solvers.learners.torchrl_learner`). What every learner shares is
:mod:`fixbench.solvers.learners.common`."""
