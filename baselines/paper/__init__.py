"""The paper-reproduction layer: protocol files (:mod:`.protocol`), the cells they expand into and their plan
(:mod:`.cells`), the engines that run the cells here, on Ray or on SLURM (:mod:`.running`), the rules that judge
the paper's claims (:mod:`.claims`), those claims judged on a report's inputs (:mod:`.verdicts`) and the full report,
the drawing layer's sections and the claims together (:mod:`.report`, what ``scripts/report.py`` calls).
``scripts/reproduce.py`` is its command; docs/reports.md its guide.
"""
