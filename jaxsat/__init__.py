"""jaxsat: batched, differentiable Separating Axis Theorem collision detection in JAX."""

from jaxsat._batching import query_batch as query_batch
from jaxsat._batching import query_pairs as query_pairs
from jaxsat._broadphase import CandidatePairs as CandidatePairs
from jaxsat._broadphase import broad_phase as broad_phase
from jaxsat._broadphase import world_aabbs as world_aabbs
from jaxsat._compound import Compound as Compound
from jaxsat._compound import CompoundPenetration as CompoundPenetration
from jaxsat._compound import compound as compound
from jaxsat._compound import compound_intersects as compound_intersects
from jaxsat._compound import compound_penetration as compound_penetration
from jaxsat._compound import concave_polygon as concave_polygon
from jaxsat._compound import stack_compounds as stack_compounds
from jaxsat._contacts import Contacts as Contacts
from jaxsat._contacts import contacts as contacts
from jaxsat._decompose import decompose as decompose
from jaxsat._halfspace import HalfSpace as HalfSpace
from jaxsat._halfspace import halfspace as halfspace
from jaxsat._mesh import load_mesh as load_mesh
from jaxsat._mesh import mesh_compound as mesh_compound
from jaxsat._poses import Pose as Pose
from jaxsat._poses import pose2 as pose2
from jaxsat._poses import pose3 as pose3
from jaxsat._queries import ClosestPoints as ClosestPoints
from jaxsat._queries import Penetration as Penetration
from jaxsat._queries import closest_points as closest_points
from jaxsat._queries import intersects as intersects
from jaxsat._queries import penetration as penetration
from jaxsat._queries import signed_distance as signed_distance
from jaxsat._scene import PlaneCollisions as PlaneCollisions
from jaxsat._scene import SceneCollisions as SceneCollisions
from jaxsat._scene import collide as collide
from jaxsat._scene import collide_capacity as collide_capacity
from jaxsat._shapes import CappedHull as CappedHull
from jaxsat._shapes import Polytope as Polytope
from jaxsat._shapes import box as box
from jaxsat._shapes import cap_hull as cap_hull
from jaxsat._shapes import capsule as capsule
from jaxsat._shapes import circle as circle
from jaxsat._shapes import moved as moved
from jaxsat._shapes import polygon as polygon
from jaxsat._shapes import polyhedron as polyhedron
from jaxsat._shapes import regular_polygon as regular_polygon
from jaxsat._shapes import rounded as rounded
from jaxsat._shapes import sphere as sphere
from jaxsat._shapes import stack as stack
from jaxsat._smoothing import smoothing_error_bound as smoothing_error_bound

__version__ = "0.1.0"

__all__ = [
    "CandidatePairs",
    "CappedHull",
    "ClosestPoints",
    "Compound",
    "CompoundPenetration",
    "Contacts",
    "HalfSpace",
    "Penetration",
    "PlaneCollisions",
    "Polytope",
    "Pose",
    "SceneCollisions",
    "box",
    "broad_phase",
    "cap_hull",
    "capsule",
    "circle",
    "closest_points",
    "collide",
    "collide_capacity",
    "compound",
    "compound_intersects",
    "compound_penetration",
    "concave_polygon",
    "contacts",
    "decompose",
    "halfspace",
    "intersects",
    "load_mesh",
    "mesh_compound",
    "moved",
    "penetration",
    "polygon",
    "polyhedron",
    "pose2",
    "pose3",
    "query_batch",
    "query_pairs",
    "regular_polygon",
    "rounded",
    "signed_distance",
    "smoothing_error_bound",
    "sphere",
    "stack",
    "stack_compounds",
    "world_aabbs",
]
