"""The simulated yard: layout, geometry, environment truth, routes.

``layout`` draws a 220 kV-class substation (:func:`~simulation.site.layout.generate_site`);
``geometry`` tests rays and segments against its boxes; ``environment`` gives the
ground-truth class of a position (blocked-sky share); ``route`` plans walks
through the aisles.
"""

__all__ = ["layout", "geometry", "environment", "route"]
