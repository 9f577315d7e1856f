"""The MAVLink link to one vehicle, shared by the live source (:mod:`apmcal.sources.live`) and
the parameter upload (:mod:`apmcal.link.upload`): the connection itself
(:mod:`~apmcal.link.connection`) and the parameter protocol (:mod:`~apmcal.link.params`).
"""
