"""The contact graph (paper stage b): a support tree rooted at the table plus proximity edges.

``nodes`` describes each object as seen from gravity (OBB, upward support planes, footprint
polygon); ``support`` picks each object's supporters by the likelihood
H = (1 - d_gap)(1 - d_com); ``proximity`` pairs objects whose inflated AABBs overlap;
``build`` puts it together as a :class:`r2s.graph.schema.ContactGraph`; ``draw`` plots it.
"""
