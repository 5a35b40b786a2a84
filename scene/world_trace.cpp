// The World's ray queries (closest hit, occlusion, packets, thin sheets' transmission), turning
// Embree's hits into Hits, shading at hits and spawning rays from them. Building the World is in
// world.cpp.
#include "scene/world.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "scene/texture.h"

namespace iso {
namespace {

// pbrt's gamma(n): a bound on the relative error of n float operations.
constexpr float gamma(int n) {
  constexpr float eps = 0x1p-24f;
  return n * eps / (1 - n * eps);
}

template <typename T>
Vec3<T> absv(const Vec3<T>& v) { return {std::fabs(v.x), std::fabs(v.y), std::fabs(v.z)}; }

// Iso-surface queries start from the ray's origin in double (World::intersect and occluded
// pass it in the IsoRayContext): for an instance, Embree's own object-space origin carries
// the float rounding of the world origin and of the transform.
RTCRay toEmbree(const Ray& ray) {
  RTCRay r{};
  r.org_x = ray.org.x; r.org_y = ray.org.y; r.org_z = ray.org.z;
  r.dir_x = ray.dir.x; r.dir_y = ray.dir.y; r.dir_z = ray.dir.z;
  r.tnear = ray.tnear;
  r.tfar = ray.tfar;
  r.mask = ray.mask;
  return r;
}

}  // namespace

const World::GeometryRecord& World::recordOf(const RTCHit& hit) const {
  if (hit.instID[0] != RTC_INVALID_GEOMETRY_ID) return m_instanceRecords[m_top[hit.instID[0]].instance][hit.geomID];
  return m_top[hit.geomID];
}

namespace {

StartClass startClassOf(const Ray& ray) { return ray.fromInside ? StartClass::Inside : StartClass::Outside; }

void startFromSurface(const Ray& ray, const std::vector<SurfaceInfo>& surfaces, IsoRayLane& lane) {
  if (ray.fromSurface < 0) return;
  lane.startSurface = surfaces[ray.fromSurface].surface.get();
  lane.start = startClassOf(ray);
  if (ray.fromCap) {
    lane.gridRay.capClip = &lane.startSurface->clip();
    lane.gridRay.capOrder = lane.startSurface->order();
  }
}

// Lane i of an Embree packet of width N as a single ray and hit (Embree's rtcGetRayHitFromRayHitN,
// with the float fields only).
RTCRayHit laneOf(const RTCRayHit8& packet, unsigned i) {
  RTCRayHit rh{};
  rh.ray.tfar = packet.ray.tfar[i];
  rh.hit.Ng_x = packet.hit.Ng_x[i]; rh.hit.Ng_y = packet.hit.Ng_y[i]; rh.hit.Ng_z = packet.hit.Ng_z[i];
  rh.hit.u = packet.hit.u[i]; rh.hit.v = packet.hit.v[i];
  rh.hit.primID = packet.hit.primID[i];
  rh.hit.geomID = packet.hit.geomID[i];
  for (unsigned l = 0; l < RTC_MAX_INSTANCE_LEVEL_COUNT; ++l) rh.hit.instID[l] = packet.hit.instID[l][i];
  return rh;
}

// What the iso-surface callbacks need of `ray` (its world origin in double, held by the caller in
// `origin`): the lane's ray in double, its far end and its start class.
void setLane(const Ray& ray, const Vec3d& origin, const std::vector<SurfaceInfo>& surfaces, IsoRayLane& lane) {
  lane.origin = &origin;
  lane.direction = Vec3d(ray.dir);
  lane.tfar = ray.tfar;
  startFromSurface(ray, surfaces, lane);
}

// Lane i of an 8-ray Embree packet set to `ray`.
void packLane(const Ray& ray, int i, RTCRay8& packet) {
  const RTCRay r = toEmbree(ray);
  packet.org_x[i] = r.org_x; packet.org_y[i] = r.org_y; packet.org_z[i] = r.org_z;
  packet.dir_x[i] = r.dir_x; packet.dir_y[i] = r.dir_y; packet.dir_z[i] = r.dir_z;
  packet.tnear[i] = r.tnear;
  packet.tfar[i] = r.tfar;
  packet.mask[i] = r.mask;
  packet.time[i] = 0;
  packet.flags[i] = 0;
}

}  // namespace

// The iso-surface hit at `t` on `ray`; `normal` in the surface's object space.
void World::fillIsoHit(const Ray& ray, int surface, double t, float tError, Vec3d normal,
                       bool insideAfter, bool cap, const Transform* toWorld, Hit& hit) const {
  const SurfaceInfo& info = m_surfaces[surface];
  hit.t = float(t);
  hit.material = info.material;
  hit.surface = surface;
  hit.tError = tError;
  hit.insideAfter = insideAfter;
  hit.cap = cap;
  // In double from the double origin: the bound is the intersector's, plus double rounding.
  const Vec3d org = ray.origin(), dir(ray.dir);
  hit.position64 = org + dir * t;
  hit.position = Vec3f(hit.position64);
  const Vec3d a = absv(hit.position64);
  const double rounding = 4 * 0x1p-52 * (std::max({a.x, a.y, a.z}) + length(dir) * std::fabs(t));
  hit.pError = Vec3f(absv(dir) * double(tError) + Vec3d(rounding, rounding, rounding));
  if (toWorld) normal = toWorld->normal(normal);
  hit.normal = Vec3f(normalize(normal));
  // The spawn offset. pbrt's (the error bound projected on the normal) is wide at a near-
  // tangent hit, where the bound is a bracket of values below rounding, and a ray spawned that
  // far off steps over a pair of crossings close behind (33 per million lost on the real
  // volumes). A ray leaving an iso-surface carries its class, so a crossing it steps over is
  // found anyway; the offset only has to clear the rounding of the float traversal's grid
  // coordinates, or the hit is found again at t = 0 by its own ray, over and over.
  const Grid& grid = *m_volumes[info.volume].grid;
  const Vec3d gridCoord = (info.surface->objectOrigin(hit.position64) - grid.origin()) / grid.spacing();
  const Vec3d g = absv(gridCoord);
  const Vec3d s = grid.spacing();
  double scale = std::max({s.x, s.y, s.z});
  if (toWorld) {
    const Vec3d rows = toWorld->absRowSums();
    scale *= std::max({rows.x, rows.y, rows.z});
  }
  const double gridRounding = 8 * 0x1p-24 * (std::max({g.x, g.y, g.z}) + 1) * scale;
  hit.spawnOffset = float(std::min(dot(absv(Vec3d(hit.normal)), Vec3d(hit.pError)), gridRounding));
  // A cap is exact to double rounding; a ray leaving it starts off its plane along the normal by
  // the float traversal's rounding, far enough that its own clip extent is decided on its side.
  if (cap) hit.spawnOffset = float(gridRounding);
  if (!info.solidAbove) hit.normal = -hit.normal;
  // The shading normal: the smooth gradient at the hit (the cell's own gradient jumps across
  // cell faces, which shades in facets). It only shades; orientation, spawning and the class
  // stay with the exact surface's geometric normal, which it may not contradict.
  hit.shading = hit.normal;
  if (info.smoothNormals && !cap) {  // (a cap is flat)
    Vec3d n = -grid.smoothGradient(gridCoord) / grid.spacing();
    if (toWorld) n = toWorld->normal(n);
    if (!info.solidAbove) n = -n;
    const double len = length(n);
    if (len > 0 && std::isfinite(len) && dot(n, Vec3d(hit.normal)) > 0) hit.shading = Vec3f(n / len);
  }
}

// A ray leaving an iso-surface whose origin lies in an inactive brick of that surface: no
// brick query sees that cell (IsoSurface::crossesAtInactiveStart).
bool World::crossesAtInactiveStart(const Ray& ray, Hit* hit, TraversalStats& stats) const {
  if (ray.fromSurface < 0) return false;
  const IsoSurface& surface = *m_surfaces[ray.fromSurface].surface;
  const Vec3d org = surface.objectOrigin(ray.origin());
  const Vec3d dir = surface.objectDirection(Vec3d(ray.dir));
  SurfaceHit sh;
  if (!surface.crossesAtInactiveStart(org, dir, ray.tnear, ray.tfar, startClassOf(ray), hit ? &sh : nullptr, stats))
    return false;
  if (hit) {
    *hit = Hit();
    hit->incoming = ray.dir;
    const Transform& toWorld = m_volumes[m_surfaces[ray.fromSurface].volume].transform;
    fillIsoHit(ray, ray.fromSurface, sh.t, float(sh.tError), Vec3d(sh.normal), sh.insideAfter, sh.cap,
               toWorld.isIdentity() ? nullptr : &toWorld, *hit);
  }
  return true;
}

// A ray leaving an iso-surface hit near its volume's box can start just outside the box (the
// spawn offset points out of it). Its start class applies where it meets the field, so its
// origin moves back onto the box: to where the line of the offset (through the hit and the
// origin: the incoming ray, on which the crossing and its class were decided), followed from
// the hit towards the origin, leaves the box. The crossing lies in the box, so that point is
// on the side of it the ray's class names, even where rounding put the hit itself outside.
// Moving each coordinate onto the box alone would step sideways off that line, and where the
// surface meets the box face within that step, onto its other side: an extra pair of hits at
// the box face (11 in 3e8 rays on a rough field). Embree then traces the same line as the
// iso-surface queries (IsoSurface moves what rounding leaves outside).
Ray World::startInsideVolume(const Ray& ray) const {
  if (ray.fromSurface < 0) return ray;
  const SurfaceInfo& info = m_surfaces[ray.fromSurface];
  const VolumeInfo& volume = m_volumes[info.volume];
  const Grid& grid = *volume.grid;
  const Vec3d world = ray.origin();
  const Vec3d o = info.surface->objectOrigin(world);
  const Vec3d lo = grid.origin();
  const Vec3d hi = lo + Vec3d(grid.dims() - Vec3i{1, 1, 1}) * grid.spacing();
  auto clampToBox = [&](const Vec3d& p) {
    return Vec3d{std::clamp(p.x, lo.x, hi.x), std::clamp(p.y, lo.y, hi.y), std::clamp(p.z, lo.z, hi.z)};
  };
  Vec3d c = clampToBox(o);
  if (c == o || !isFinite(o)) return ray;
  // The line from + s (o - from): where it is in the box, s in [enter, leave].
  const Vec3d from = info.surface->objectOrigin(world - ray.fromOffset);  // the hit
  double enter, leave;
  if (isFinite(from) && lineInBox(from, o - from, lo, hi, enter, leave) && leave < 1)
    c = clampToBox(from + (o - from) * leave);  // the clamp: rounding only
  Ray moved = ray;
  moved.org64 = volume.transform.isIdentity() ? c : volume.transform.point(c);
  moved.org = Vec3f(*moved.org64);
  return moved;
}

bool World::intersect(const Ray& ray, Hit& hit, TraversalStats& stats) const {
  if (ray.fromSurface < 0) return trace(ray, hit, stats);
  const Ray start = startInsideVolume(ray);
  return crossesAtInactiveStart(start, &hit, stats) || trace(start, hit, stats);
}

bool World::trace(const Ray& ray, Hit& hit, TraversalStats& stats) const {
  RTCRayHit rh{};
  rh.ray = toEmbree(ray);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  if (!needsLanes()) {
    // No callback reads a lane (its setup is ~80 stores a ray).
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    rtcIntersect1(m_scene, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    fillTriangleHit(ray, rh, recordOf(rh.hit), hit);
    return true;
  }
  IsoRayLane lane;
  IsoRayContext context(&lane);
  const Vec3d origin = ray.origin();
  setLane(ray, origin, m_surfaces, lane);
  rtcIntersect1(m_scene, &context.embree, &rh);
  stats.add(context.stats);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  fillHit(ray, rh, lane, hit);
  return true;
}

// What intersect() and occluded() do before Embree, for each ray of a packet: a ray leaving an
// iso-surface starts on its volume's box, and may cross at once where its start cell is seen by
// no brick query (done[i], with hits[i] filled if `hits` is given); every other ray becomes a
// valid lane of `packet` with its iso-surface data. False if no ray is left for Embree.
bool World::packRays(const Ray* rays, int n, Hit* hits, bool* done, TraversalStats& stats, PacketLanes& p,
                     RTCRay8& packet) const {
  if (n < 1 || n > kPacket) throw std::logic_error("World::intersectPacket/occludedPacket: 1 to 8 rays");
  bool any = false;
  for (int i = 0; i < kPacket; ++i) {
    p.valid[i] = 0;
    if (i < n) {
      // (startInsideVolume returns a ray not spawned from an iso-surface as it is: no copy then.)
      const Ray& start = *(p.start[i] = rays[i].fromSurface < 0 ? &rays[i] : &p.moved.emplace(i, startInsideVolume(rays[i])));
      done[i] = rays[i].fromSurface >= 0 && crossesAtInactiveStart(start, hits ? &hits[i] : nullptr, stats);
      if (!done[i]) {
        if (needsLanes()) setLane(start, p.origin.emplace(i, start.origin()), m_surfaces, p.lanes.construct(i));
        packLane(start, i, packet);
        p.valid[i] = -1;
        any = true;
        continue;
      }
    }
    // A lane Embree does not trace (no ray, or one that crossed at its start) is invalid, and
    // fully written all the same: Embree's vector code loads every lane before it masks
    // (valgrind's memcheck saw it branch on an unwritten one).
    packLane(Ray{}, i, packet);
    packet.tnear[i] = 0;
    packet.tfar[i] = -INFINITY;
  }
  return any;
}

void World::intersectPacket(const Ray* rays, int n, Hit* hits, bool* found, TraversalStats& stats) const {
  if (!m_nativePackets) {
    for (int i = 0; i < n; ++i) found[i] = intersect(rays[i], hits[i], stats);
    return;
  }
  PacketLanes p;
  alignas(32) RTCRayHit8 packet;
  for (int i = 0; i < kPacket; ++i) {
    packet.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
    packet.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
  }
  if (!packRays(rays, n, hits, found, stats, p, packet.ray)) return;
  IsoRayContext context(p.lanes.data());
  rtcIntersect8(p.valid, m_scene, &context.embree, &packet);
  stats.add(context.stats);
  for (int i = 0; i < n; ++i) {
    if (!p.valid[i] || packet.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
    fillHit(*p.start[i], laneOf(packet, unsigned(i)), p.lanes[i], hits[i]);
    found[i] = true;
  }
}

void World::occludedPacket(const Ray* rays, int n, bool* blocked, TraversalStats& stats) const {
  if (!m_nativePackets) {
    for (int i = 0; i < n; ++i) blocked[i] = occluded(rays[i], stats);
    return;
  }
  PacketLanes p;
  alignas(32) RTCRay8 packet;
  if (!packRays(rays, n, nullptr, blocked, stats, p, packet)) return;
  IsoRayContext context(p.lanes.data());
  rtcOccluded8(p.valid, m_scene, &context.embree, &packet);
  stats.add(context.stats);
  for (int i = 0; i < n; ++i)
    if (p.valid[i] && packet.tfar[i] < 0) blocked[i] = true;
}

// The hit Embree found for `ray` (in `rh`), with the lane's iso-surface result.
[[gnu::always_inline]] inline void World::fillHit(const Ray& ray, const RTCRayHit& rh, const IsoRayLane& lane, Hit& hit) const {
  const GeometryRecord& rec = recordOf(rh.hit);
  // Every field is written, each kind its own and the other kind's defaults, instead of a clear
  // of the whole record first (a Hit is ~170 bytes, written for every ray that hits).
  if (!rec.mesh) {
    hit.incoming = ray.dir;
    hit.mesh = hit.light = hit.triangle = hit.slice = -1;
    hit.b1 = hit.b2 = 0;
    hit.triangles = nullptr;
    hit.prim = 0;
    hit.toWorld = nullptr;
    // Iso-surface: the intersector's bound on t becomes a bound on the position.
    fillIsoHit(ray, rec.surface, lane.t, lane.tError, Vec3d{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z},
               lane.insideAfter, lane.cap, rec.identity ? nullptr : &rec.toWorld, hit);
    return;
  }
  fillTriangleHit(ray, rh, rec, hit);
}

// A triangle hit: position from barycentrics with pbrt-v4's bound (Pharr et al., 6.8.5).
[[gnu::always_inline]] inline void World::fillTriangleHit(const Ray& ray, const RTCRayHit& rh, const GeometryRecord& rec,
                                                          Hit& hit) const {
  hit.incoming = ray.dir;
  hit.t = rh.ray.tfar;
  hit.tError = 0;
  hit.surface = -1;
  hit.spawnOffset = 0;
  hit.insideAfter = hit.cap = false;
  hit.material = rec.material;
  const TriangleMesh& m = *rec.mesh;
  const unsigned prim = rh.hit.primID;
  const uint32_t i0 = m.indices[3 * prim], i1 = m.indices[3 * prim + 1], i2 = m.indices[3 * prim + 2];
  const float b1 = rh.hit.u, b2 = rh.hit.v, b0 = 1 - b1 - b2;
  const Vec3f p0 = m.positions[i0], p1 = m.positions[i1], p2 = m.positions[i2];
  const Vec3f pObj = p0 * b0 + p1 * b1 + p2 * b2;
  const Vec3f errObj = (absv(p0 * b0) + absv(p1 * b1) + absv(p2 * b2)) * gamma(7);
  Vec3f ng = cross(p1 - p0, p2 - p0);
  hit.mesh = rec.meshDesc;
  hit.slice = rec.slice;
  hit.light = rec.light;
  hit.triangle = rec.light >= 0 ? int(prim) : -1;
  hit.b1 = b1;
  hit.b2 = b2;
  hit.triangles = &m;
  hit.prim = prim;
  hit.toWorld = rec.identity ? nullptr : &rec.toWorld;
  Vec3f ns = m.normals.empty() ? Vec3f{0, 0, 0} : m.normals[i0] * b0 + m.normals[i1] * b1 + m.normals[i2] * b2;
  if (rec.identity) {
    hit.position = pObj;
    hit.pError = errObj;
    hit.position64 = Vec3d(pObj);
  } else {
    const Transform& t = rec.toWorld;
    hit.position = Vec3f(t.point(Vec3d(pObj)));
    const Vec3d rows = t.absRowSums(), trans{t.m[0][3], t.m[1][3], t.m[2][3]};
    const float e = std::max({errObj.x, errObj.y, errObj.z});
    const Vec3f pAbs = absv(pObj);
    const float pMax = std::max({pAbs.x, pAbs.y, pAbs.z});
    hit.pError = Vec3f(rows * double(e)) + (Vec3f(rows * double(pMax)) + absv(Vec3f(trans)) + absv(hit.position)) * gamma(3);
    hit.position64 = Vec3d(hit.position);
    ng = Vec3f(t.normal(Vec3d(ng)));
    if (length(ns) > 0) ns = Vec3f(t.normal(Vec3d(ns)));
  }
  const float ngLen = length(ng);
  hit.normal = ngLen > 0 ? ng * (1 / ngLen) : -ray.dir;
  const float nsLen = length(ns);
  hit.shading = nsLen > 0 && std::isfinite(nsLen) ? ns * (1 / nsLen) : hit.normal;
  // The geometric normal follows the shading normals' side (pbrt's convention): vertex
  // normals say which way is out even where the winding disagrees.
  if (dot(hit.normal, hit.shading) < 0) hit.normal = -hit.normal;
}

TextureFrame World::textureFrame(const Hit& hit) {
  TextureFrame f;
  if (!hit.triangles) return f;
  const TriangleMesh& m = *hit.triangles;
  const unsigned prim = hit.prim;
  const uint32_t i0 = m.indices[3 * prim], i1 = m.indices[3 * prim + 1], i2 = m.indices[3 * prim + 2];
  const float b1 = hit.b1, b2 = hit.b2, b0 = 1 - b1 - b2;
  f.uv = {b1, b2};
  if (m.uvs.empty()) return f;
  const Vec3f p0 = m.positions[i0], p1 = m.positions[i1], p2 = m.positions[i2];
  const Vec2f t0 = m.uvs[i0], t1 = m.uvs[i1], t2 = m.uvs[i2];
  f.uv = {t0.x * b0 + t1.x * b1 + t2.x * b2, t0.y * b0 + t1.y * b1 + t2.y * b2};
  const float du1 = t1.x - t0.x, dv1 = t1.y - t0.y, du2 = t2.x - t0.x, dv2 = t2.y - t0.y;
  const float det = du1 * dv2 - dv1 * du2;
  if (std::fabs(det) > 1e-12f) {
    f.dpdu = ((p1 - p0) * dv2 - (p2 - p0) * dv1) / det;
    f.dpdv = ((p2 - p0) * du1 - (p1 - p0) * du2) / det;
  }
  if (hit.toWorld) {
    f.dpdu = Vec3f(hit.toWorld->vector(Vec3d(f.dpdu)));
    f.dpdv = Vec3f(hit.toWorld->vector(Vec3d(f.dpdv)));
  }
  return f;
}

bool World::occluded(const Ray& ray, TraversalStats& stats) const {
  if (ray.fromSurface < 0) return traceShadow(ray, stats);
  const Ray start = startInsideVolume(ray);
  return crossesAtInactiveStart(start, nullptr, stats) || traceShadow(start, stats);
}

Vec3f World::transmittance(const Ray& shadow, TraversalStats& stats) const {
  if (!m_hasThin) return occluded(shadow, stats) ? Vec3f{0, 0, 0} : Vec3f{1, 1, 1};
  Hit hit;
  Vec3f T;
  return intersectPastThin(shadow, hit, T, stats) ? Vec3f{0, 0, 0} : T;
}

bool World::intersectPastThin(const Ray& first, Hit& hit, Vec3f& T, TraversalStats& stats) const {
  T = {1, 1, 1};
  if (!m_hasThin) return intersect(first, hit, stats);
  // Hit by hit: each thin crossing scales the light. A ray to a point (spawnRayTo) keeps its
  // target; any other ray its direction.
  const bool toPoint = first.tfar < 1;
  const Vec3f target = Vec3f(first.origin() + Vec3d(first.dir));
  const Vec3f dir = normalize(first.dir);
  Ray ray = first;
  for (int crossing = 0; crossing < 64; ++crossing) {
    if (!intersect(ray, hit, stats)) return false;
    const Material& m = m_materials[size_t(hit.material)];
    if (!(m.type == MaterialType::Dielectric && m.thin)) return true;
    T = T * albedo(hit) * (1 - thinDielectricReflectance(dot(dir, hit.normal), m.ior));
    if (!(std::max({T.x, T.y, T.z}) > 0)) return true;  // nothing passes: as good as opaque
    ray = toPoint ? spawnRayTo(hit, target) : spawnRay(hit, first.dir);
  }
  return true;
}

bool World::traceShadow(const Ray& ray, TraversalStats& stats) const {
  if (!needsLanes()) {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRay r = toEmbree(ray);
    rtcOccluded1(m_scene, &context, &r);
    return r.tfar < 0;
  }
  IsoRayLane lane;
  IsoRayContext context(&lane);
  const Vec3d origin = ray.origin();
  setLane(ray, origin, m_surfaces, lane);
  RTCRay r = toEmbree(ray);
  rtcOccluded1(m_scene, &context.embree, &r);
  stats.add(context.stats);
  return r.tfar < 0;
}

// Each slice's polygon: the plane cut through the volume's grid box (a parallelepiped in world
// space), its corners in order around their centre, as a triangle fan in world space.

bool World::gridCoordinates(int volume, const Vec3d& world, Vec3d& g) const {
  const VolumeInfo& vol = m_volumes[size_t(volume)];
  const Grid& grid = *vol.grid;
  g = ((vol.transform.isIdentity() ? world : vol.toObject.point(world)) - grid.origin()) / grid.spacing();
  const Vec3d hi = Vec3d(grid.dims() - Vec3i{1, 1, 1});
  const double slack = 1e-9 * (std::max({std::fabs(g.x), std::fabs(g.y), std::fabs(g.z)}) + 1);
  for (int a = 0; a < 3; ++a)
    if (!(g[a] >= -slack && g[a] <= hi[a] + slack)) return false;
  return true;
}

double World::colorValue(const ColorByDesc& c, int ownVolume, const Vec3d& world) const {
  const int volume = c.volume >= 0 ? c.volume : ownVolume;
  Vec3d g;
  if (!gridCoordinates(volume, world, g)) return NAN;
  const VolumeInfo& vol = m_volumes[size_t(volume)];
  if (c.volume >= 0) return vol.grid->interpolate(g);
  // The gradient's magnitude in world units: per grid step to per object unit, then the
  // inverse transpose of the volume's placement.
  const Vec3d d = vol.grid->smoothGradient(g) / vol.grid->spacing();
  if (vol.transform.isIdentity()) return length(d);
  const Transform& inv = vol.toObject;
  Vec3d worldGradient;
  for (int i = 0; i < 3; ++i) worldGradient[i] = inv.m[0][i] * d.x + inv.m[1][i] * d.y + inv.m[2][i] * d.z;
  return length(worldGradient);
}

Vec3f World::sliceColor(const Hit& hit) const {
  const SliceInfo& s = m_slices[size_t(hit.slice)];
  Vec3d g;
  gridCoordinates(s.volume, hit.position64, g);  // on the slice's polygon: inside (the value clamps)
  return s.map.linear(m_volumes[size_t(s.volume)].grid->interpolate(g), s.lo, s.hi);
}

Vec3f World::albedo(const Hit& hit) const { return albedo(hit, nullptr); }

Vec3f World::albedo(const Hit& hit, const TextureFrame* frame) const {
  if (hit.slice >= 0)  // a slice: its map of the volume's value, or black if it only emits
    return m_slices[size_t(hit.slice)].emit ? Vec3f{0, 0, 0} : sliceColor(hit);
  if (hit.surface >= 0) {
    const SurfaceInfo& s = m_surfaces[size_t(hit.surface)];
    if (const std::optional<ColorByDesc>& by = hit.cap ? s.capColorBy : s.colorBy) {
      const double v = colorValue(*by, s.volume, hit.position64);
      return std::isfinite(v) ? by->map.linear(v, by->lo, by->hi) : hit.cap ? s.capNanColor : s.nanColor;
    }
  }
  const Material& m = m_materials[hit.material];
  Vec3f c = m.color;
  if (m.colorTexture >= 0) {
    const Vec2f uv = frame ? frame->uv : textureFrame(hit).uv;
    c = c * m_textures[m.colorTexture].lookup(uv.x, uv.y).rgb();
  }
  return c;
}

Bsdf World::bsdf(const Hit& hit, const Vec3f& wo) const {
  const Material& m = m_materials[hit.material];
  const TextureFrame tf = textureFrame(hit);  // (dpdu is the shading frame's hint even untextured)
  float metallic = m.metallic, roughness = m.roughness;
  if (m.metallicRoughnessTexture >= 0) {
    // glTF: roughness in green, metalness in blue, both linear.
    const Vec4f mr = m_textures[m.metallicRoughnessTexture].lookup(tf.uv.x, tf.uv.y);
    roughness *= mr.y;
    metallic *= mr.z;
  }
  Vec3f n = hit.shading;
  if (m.normalTexture >= 0 && length(tf.dpdu) > 0) {
    // Tangent space of the texture: x along +u, y towards the image top (-v), z the normal.
    const Vec4f c = m_textures[m.normalTexture].lookup(tf.uv.x, tf.uv.y);
    const Vec3f local{(2 * c.x - 1) * m.normalScale, (2 * c.y - 1) * m.normalScale, 2 * c.z - 1};
    const Vec3f t = normalize(tf.dpdu - n * dot(n, tf.dpdu));
    Vec3f b = cross(n, t);
    if (dot(b, tf.dpdv) > 0) b = -b;
    const Vec3f mapped = t * local.x + b * local.y + n * local.z;
    if (length(mapped) > 0 && std::isfinite(length(mapped))) n = normalize(mapped);
  }
  Bsdf b(m.type, Frame::fromNormal(n, tf.dpdu), albedo(hit, &tf), metallic, roughness, m.ior, m.thin);
  b.setOutgoing(wo);
  return b;
}

Vec3f World::emitted(const Hit& hit, const Vec3f& wo) const {
  const Material& m = m_materials[hit.material];
  if (!m.emits()) return {0, 0, 0};
  if (hit.slice >= 0) return sliceColor(hit);  // an unlit slice shows its map on both sides
  if (hit.surface < 0 && hit.light >= 0) return m_lights[hit.light].emitted(hit.triangle, hit.b1, hit.b2, wo);
  // Emissive iso-surfaces: front side is out of the solid.
  if (!m.twoSided && dot(wo, hit.normal) <= 0) return {0, 0, 0};
  return m.emission;
}

namespace {

// Whether a ray leaving an iso-surface hit in direction w goes on through the surface: when w
// heads to the same side of the normal as the incoming ray (w = incoming, the watertight
// check's case, always does); one of them in the plane decides by w against the incoming ray.
bool goesThrough(const Hit& hit, const Vec3f& w) {
  const float a = dot(w, hit.normal), b = dot(hit.incoming, hit.normal);
  return a != 0 && b != 0 ? (a > 0) == (b > 0) : dot(w, hit.incoming) > 0;
}

// A triangle hit's offset origin (offsetRayOrigin), in float: where Embree sees it.
Vec3f offsetTriangleOrigin(const Hit& hit, const Vec3f& w) {
  const Vec3f nf = dot(w, hit.normal) < 0 ? -hit.normal : hit.normal;  // towards the leaving side
  const Vec3d n(nf);
  const Vec3d& p = hit.position64;
  // pbrt rejects hits at t = 0, Embree accepts them (t >= tnear = 0): an origin must lie
  // strictly on the leaving side even where the bound is 0 (a hit on the plane y = 0 has no
  // error in y). Embree intersects triangles in float: the floor is one float spacing at the
  // point's magnitude (a representable move, never a denormal, which Embree flushes to zero).
  const double largest = std::max(std::max(std::fabs(p.x), std::fabs(p.y)), std::fabs(p.z));
  const double floor = std::max(largest * 0x1p-23, 1e-20);
  const double d = std::max(std::fabs(n.x) * double(hit.pError.x) + std::fabs(n.y) * double(hit.pError.y) +
                                std::fabs(n.z) * double(hit.pError.z),
                            floor);
  // Then rounded away from the surface in float.
  Vec3f o(p + n * d);
  for (int i = 0; i < 3; ++i) {
    if (nf[i] > 0) o[i] = nextFloatUp(o[i]);
    else if (nf[i] < 0) o[i] = nextFloatDown(o[i]);
  }
  return o;
}

}  // namespace

Vec3d offsetRayOrigin(const Hit& hit, const Vec3f& w) {
  if (hit.surface < 0) return Vec3d(offsetTriangleOrigin(hit, w));
  const Vec3d p = hit.position64;
  const Vec3d a = absv(p);
  // As for triangles, the origin lies strictly on the leaving side even where the bound is 0;
  // iso-surfaces are intersected from the double origin, so the floor is one double spacing.
  const double floor = std::max(std::max({a.x, a.y, a.z}) * 0x1p-52, 1e-20);
  const double d = std::max(double(hit.spawnOffset), floor);
  if (!hit.cap && length(Vec3d(hit.incoming)) > 0) {
    // An iso-surface's origin moves along the incoming ray, on whose line the crossing and its
    // class were decided: forward past the hit for a ray that goes through, back for one that
    // turns back. Along the normal it could land on the wrong side where the hit sits on a
    // cell face: the normal is the gradient of one cell, and the surface bends at the face
    // (a double count found at 1e7 rays: the next ray started on the old side with the new
    // class and reported the same crossing again).
    const Vec3d in = normalize(Vec3d(hit.incoming));
    return p + in * (goesThrough(hit, w) ? d : -d);
  }
  const Vec3d n(dot(w, hit.normal) < 0 ? -hit.normal : hit.normal);  // towards the leaving side
  return p + n * d;
}

namespace {

// The ray leaving `hit` towards w, but for its direction (and far end).
Ray leaving(const Hit& hit, const Vec3f& w) {
  Ray r;
  r.tnear = 0;
  if (hit.surface < 0) {
    r.org = offsetTriangleOrigin(hit, w);
    return r;
  }
  const Vec3d o = offsetRayOrigin(hit, w);
  r.org = Vec3f(o);
  r.org64 = o;
  r.fromOffset = o - hit.position64;
  r.fromSurface = hit.surface;
  r.fromCap = hit.cap;
  r.fromInside = goesThrough(hit, w) ? hit.insideAfter : !hit.insideAfter;
  return r;
}

}  // namespace

Ray spawnRay(const Hit& hit, const Vec3f& dir) {
  Ray r = leaving(hit, dir);
  r.dir = dir;
  return r;
}

Ray spawnRayTo(const Hit& hit, const Vec3f& target) {
  Ray r = leaving(hit, target - hit.position);
  r.dir = Vec3f(Vec3d(target) - r.origin());
  r.tfar = 1 - 1e-4f;
  return r;
}

Vec3f World::environment(const Vec3f& dir) const {
  Vec3f sum{0, 0, 0};
  for (int i : m_environmentLights) sum += m_lights[i].environment(dir);
  return sum;
}

}  // namespace iso
