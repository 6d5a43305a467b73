// Validate a glTF/GLB file with the Khronos glTF validator (npm gltf-validator).
// Usage: node scripts/validate_gltf.js FILE.glb   -> prints the JSON report's issues summary
const fs = require("fs");
const path = require("path");
const validator = require(process.env.GLTF_VALIDATOR || "gltf-validator");
const file = process.argv[2];
const data = new Uint8Array(fs.readFileSync(file));
validator.validateBytes(data, {
  uri: path.basename(file),
  externalResourceFunction: (uri) => new Promise((resolve, reject) => {
    fs.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)),
      (err, buf) => err ? reject(err.toString()) : resolve(new Uint8Array(buf)));
  }),
}).then((report) => {
  console.log(JSON.stringify(report.issues));
}).catch((err) => { console.error(String(err)); process.exit(2); });
