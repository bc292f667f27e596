"""The papers' experiments on bundled data: GPDM missing-frame fill-in (Wang et al. 2008, Table 2)
and the held-out log-likelihood of the Lie-algebra prior (Simo-Serra et al. 2015)."""
