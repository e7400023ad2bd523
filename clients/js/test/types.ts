// Type-checked (tsc --noEmit), never run: index.d.ts used as a TypeScript game would.
import {
  CloudscapeClient,
  billboardsAt,
  decodeBillboards,
  keyframeOf,
  shadowMaps,
  threeArrays,
  worldClock,
  type BillboardFrame,
  type DerivedShadow,
  type HeldTile,
  type Keyframe,
  type ThreeArrays,
  type World,
} from 'cloudscape-client';

export async function draw(base: string): Promise<ThreeArrays> {
  const client = new CloudscapeClient(base, { quality: 'balanced' });
  const world: World = await client.world('default');
  const layer = world.layers[0];
  const now: number = worldClock(world, { rate: 12 })();
  const k: Keyframe = keyframeOf(layer, 0, now, world.max_time);
  const tile = { layer: layer.name, z: 0, x: 0, y: 0 };
  const at = { t: 43210, sun: [180, 45] as [number, number] };
  const bytes: ArrayBuffer = await client.tile(world, tile, 'billboards.bin', at);
  const decoded = decodeBillboards(bytes);
  const t0: number | null = decoded.header.t0;
  const frame: BillboardFrame = billboardsAt(decoded, k.t0 + k.f * k.span, await client.splats());
  const { billboards } = await client.billboardTile(world, tile, at);
  const next = await client.keyframe(world, tile, { ...at, next: true });
  const delta = decodeBillboards(bytes, billboards);
  const held: HeldTile[] = [billboards, next].map((keyframe) => ({ layer: layer.name, base: layer.base, keyframe }));
  const [shadow]: DerivedShadow[] = shadowMaps(held);
  const transmittance: number = shadow.t0[0];
  void t0;
  void delta.lattice;
  void transmittance;
  return threeArrays([frame], { origin: [0, 0, 0], eye: [0, 0, 1000] });
}
