"""What ``sern regret`` and ``sern reproduce`` run: the regret experiment over seed chunks with
resume (``regret``) and its neural-learner variant (``neural_regret``)."""
