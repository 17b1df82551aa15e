"""The body-kind protocol. A kind of body (particles today, with cloth vertices among them; rigid bodies
and fluid particles next) owns its arrays, named with its prefix as in Newton (`particle_x`,
`particle_mass`; a rigid kind's would be `body_q`, `body_mass`), and brings three parts that the hubs
inherit from, so its public names sit where users look for them (`Builder.add_particles`,
`model.particle_count`, `state.particle_x`):

  builder   a Builder mixin: its `add_*` methods, and the arrays it hands to finalize()
  model     a Model mixin: its static arrays, counts and the Taichi-scope accessors kernels read
  state     a State mixin (data-oriented: it may hold kernels): its dynamic arrays, their NumPy access
            and its read-only output (a snapshot)

and the hooks the hubs call, in `KINDS` order, for every kind (below), among them its output items
(content.py: points, meshes, lines, which every output reads). Adding a kind is a folder under
bodies/ with these parts and one entry in `bodies.KINDS`; its time stepping is a solver in the Stepper's
list (solvers.py), which reads and writes its state arrays."""

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class BodyKind:
    """One kind of body: its name (the prefix of its settings), its three parts and its hooks.

    init_builder(builder)                  the builder part's empty lists (Builder.__init__)
    finalize(builder) -> (dict, dict)      the kind's arrays for Model (keyword arguments of
                                           init_model) and its run.json settings (Builder.finalize)
    init_model(model, **arrays)            the model part's arrays and counts (Model.__init__)
    init_state(state, model)               allocate the state part's arrays (State.__init__)
    start_state(state, model)              fill them for t = 0 (Model.state)
    save_state(state, into, whole_trail)   copy them into another State of the model (State.save: a
                                           rollback point; one kernel launch per kind)
    output_items(model, state) -> list     what the kind shows now, as content items (content.py), which
                                           PLY, USD and the renderer read (Scene.frame_content)
    """

    name: str
    builder: type
    model: type
    state: type
    init_builder: Callable
    finalize: Callable
    init_model: Callable
    init_state: Callable
    start_state: Callable
    save_state: Callable
    output_items: Callable
