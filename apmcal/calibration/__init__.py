"""TODO map.

flight: the compass from an ordinary flight log — health check in heading degrees, COMPASS_*
proposal with σ, orientation search; ``apmcal log FLIGHT`` runs it (:func:`log_flight`).
"""
