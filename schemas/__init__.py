"""Message contracts, one module per service; services and contract tests import them.

``CONTRACTS`` maps a service name to its module (``ENDPOINTS``, ``EVENTS``);
``mirrorcoach schemas`` prints them.
"""

from schemas import capture, coach, dialogue, estimator, pss, simulator

CONTRACTS = {"pss": pss, "simulator": simulator, "dialogue": dialogue, "estimator": estimator, "coach": coach,
             "capture": capture}
