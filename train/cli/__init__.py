"""The command lines: ``mecanum-train`` (``train``), ``mecanum-eval`` (``evaluate``),
``mecanum-export`` (``export``) and ``mecanum-deploy-sim`` (``deploy_sim``)."""
