// A stand-in for the mechdsl program in test/activate.test.js: `view FILE --no-browser`
// prints the address line `mechdsl view` prints and waits to be stopped; anything else
// exits 1 with a message.
'use strict';

const args = process.argv.slice(2);
if (args[0] === 'view' && args[2] === '--no-browser') {
  process.stderr.write('mechdsl view: http://127.0.0.1:4567/t0ken/  (Ctrl-C to stop)\n');
  process.on('SIGINT', () => process.exit(0));
  setInterval(() => {}, 1000);
} else {
  process.stderr.write(`mechdsl: error: unknown command ${args.join(' ')}\n`);
  process.exit(1);
}
