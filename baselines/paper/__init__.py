"""The paper-reproduction layer: protocol files (:mod:`.protocol`), the cells they expand into and their plan
(:mod:`.cells`), the engines that run the cells here, on Ray or on SLURM (:mod:`.running`), and the rules that judge
the paper's claims (:mod:`.claims`).  ``scripts/reproduce.py`` is its command; docs/reports.md its guide.
"""
