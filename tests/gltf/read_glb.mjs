// Reads a .glb with third-party glTF code and prints what it found as JSON on stdout: the Khronos glTF validator's
// report (errors, warnings and their messages), then glTF-Transform's reading of the file, Draco primitives decoded
// by Google's draco3dgltf and meshopt buffer views by meshoptimizer's own decoder: every node's scale and translation,
// and every primitive's mode, indices, POSITION values (as stored: integer grid coordinates for our frames) and
// attributes (semantic -> count, type, values). Usage: node read_glb.mjs FILE.glb
import fs from 'node:fs';
import validator from 'gltf-validator';
import { NodeIO } from '@gltf-transform/core';
import { ALL_EXTENSIONS } from '@gltf-transform/extensions';
import draco3d from 'draco3dgltf';
import { MeshoptDecoder } from 'meshoptimizer';

const bytes = new Uint8Array(fs.readFileSync(process.argv[2]));
const report = await validator.validateBytes(bytes, { maxIssues: 100 });
await MeshoptDecoder.ready;
const io = new NodeIO().registerExtensions(ALL_EXTENSIONS).registerDependencies({
  'draco3d.decoder': await draco3d.createDecoderModule(),
  'meshopt.decoder': MeshoptDecoder,
});
const doc = await io.readBinary(bytes);
const out = {
  errors: report.issues.numErrors,
  warnings: report.issues.numWarnings,
  issues: report.issues.messages.filter((m) => m.severity <= 1),
  nodes: doc.getRoot().listNodes().map((n) => ({
    scale: n.getScale(),
    translation: n.getTranslation(),
    mesh: !!n.getMesh(),
  })),
  primitives: [],
};
for (const mesh of doc.getRoot().listMeshes()) {
  for (const prim of mesh.listPrimitives()) {
    const attributes = {};
    for (const semantic of prim.listSemantics()) {
      const a = prim.getAttribute(semantic);
      attributes[semantic] = { count: a.getCount(), type: a.getType(), values: Array.from(a.getArray()) };
    }
    out.primitives.push({ mode: prim.getMode(), indices: Array.from(prim.getIndices().getArray()), attributes });
  }
}
process.stdout.write(JSON.stringify(out));
