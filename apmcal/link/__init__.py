"""The MAVLink link to one vehicle, shared by the live source (:mod:`apmcal.sources.live`) and
the parameter upload: the connection itself (:mod:`~apmcal.link.connection`), the parameter
protocol (:mod:`~apmcal.link.params`), and the verified upload and restore
(:mod:`~apmcal.link.upload`: backup first, read-back, roll-back).
"""
