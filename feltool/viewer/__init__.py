"""Browser views: a robot's meshcat scene (:mod:`.scene`), a motion saved as one HTML file
(:mod:`.html`), the live viewer (:mod:`.live`) and a run's rollouts streamed, saved and replayed
(:mod:`.rollout`).

Imports from feltool: ``runs`` (a run directory's traces) and what it imports.
"""
