// activate() of extension.js against mocks of `vscode` and `vscode-languageclient/node`, so
// that it runs with plain `node test/activate.test.js` (no npm install, no VS Code): the client
// is created with the command of the setting mechdsl.server.command and started, a server
// that cannot start gives an error message naming `pip install "mechdsl[lsp]"`, a change of
// the setting restarts the client, deactivate() stops it. Exit code 0 when all pass.
'use strict';

const assert = require('assert');
const Module = require('module');
const path = require('path');

const EXTENSION = path.resolve(__dirname, '..', 'extension.js');
const MOCKED = new Set(['vscode', 'vscode-languageclient/node']);

/** A fresh world: the mocked modules' state, read and set by each test. */
function makeWorld({ setting, folders, startError } = {}) {
  const world = {
    setting, // the value of mechdsl.server.command (undefined: not set)
    folders, // workspace folder paths, or undefined
    startError, // an Error the next start() rejects with
    clients: [],
    errors: [],
    configListeners: [],
    commands: {},
    executed: [],
    editor: undefined,
  };
  class LanguageClient {
    constructor(id, name, serverOptions, clientOptions) {
      Object.assign(this, { id, name, serverOptions, clientOptions });
      this.started = false;
      this.stopped = false;
      world.clients.push(this);
    }
    start() {
      this.started = true;
      const err = world.startError;
      world.startError = undefined;
      return err ? Promise.reject(err) : Promise.resolve();
    }
    stop() {
      this.stopped = true;
      return Promise.resolve();
    }
  }
  world.vscode = {
    workspace: {
      getConfiguration(section) {
        assert.strictEqual(section, 'mechdsl');
        return { get: (key) => (key === 'server.command' ? world.setting : undefined) };
      },
      get workspaceFolders() {
        return world.folders && world.folders.map((p) => ({ uri: { fsPath: p } }));
      },
      onDidChangeConfiguration(listener) {
        world.configListeners.push(listener);
        return { dispose() {} };
      },
    },
    window: {
      showErrorMessage(message) {
        world.errors.push(message);
        return Promise.resolve(undefined);
      },
      get activeTextEditor() {
        return world.editor;
      },
    },
    commands: {
      registerCommand(name, fn) {
        world.commands[name] = fn;
        return { dispose() {} };
      },
      executeCommand(...args) {
        world.executed.push(args);
        return Promise.resolve();
      },
    },
  };
  world.languageclient = { LanguageClient, TransportKind: { stdio: 0, ipc: 1, pipe: 2, socket: 3 } };
  return world;
}

const originalResolve = Module._resolveFilename;
Module._resolveFilename = function (request, ...rest) {
  return MOCKED.has(request) ? `mock:${request}` : originalResolve.call(this, request, ...rest);
};

/** extension.js loaded anew against the world's mocks. */
function load(world) {
  for (const [name, exports] of [['vscode', world.vscode],
    ['vscode-languageclient/node', world.languageclient]]) {
    const id = `mock:${name}`;
    require.cache[id] = { id, filename: id, loaded: true, exports };
  }
  delete require.cache[EXTENSION];
  return require(EXTENSION);
}

async function activated(options) {
  const world = makeWorld(options);
  const extension = load(world);
  const context = { subscriptions: [] };
  await extension.activate(context);
  return { world, extension, context };
}

const tests = [];
function test(name, fn) {
  tests.push({ name, fn });
}

test('the default command starts `mechdsl lsp` for .mech files on disk', async () => {
  const { world, context } = await activated();
  assert.strictEqual(world.clients.length, 1);
  const client = world.clients[0];
  assert.strictEqual(client.serverOptions.command, 'mechdsl');
  assert.deepStrictEqual(client.serverOptions.args, ['lsp']);
  // a transport would add "--stdio" to the arguments, which `mechdsl lsp` refuses
  assert.strictEqual(client.serverOptions.transport, undefined);
  assert.deepStrictEqual(client.clientOptions.documentSelector,
    [{ scheme: 'file', language: 'mech' }]);
  assert.ok(client.started, 'start() was not called');
  assert.deepStrictEqual(world.errors, []);
  assert.ok(context.subscriptions.length >= 1, 'the configuration listener is not disposed');
});

test('the command comes from mechdsl.server.command', async () => {
  const { world } = await activated({ setting: ['/path/.venv/bin/mechdsl', 'lsp'] });
  assert.strictEqual(world.clients.length, 1);
  assert.strictEqual(world.clients[0].serverOptions.command, '/path/.venv/bin/mechdsl');
  assert.deepStrictEqual(world.clients[0].serverOptions.args, ['lsp']);
  assert.ok(world.clients[0].started);
});

test('a relative program and ${workspaceFolder} are taken from the workspace folder', async () => {
  const folder = path.resolve('/work/project');
  let { world } = await activated({ setting: ['.venv/bin/mechdsl', 'lsp'], folders: [folder] });
  assert.strictEqual(world.clients[0].serverOptions.command,
    path.join(folder, '.venv', 'bin', 'mechdsl'));
  assert.strictEqual(world.clients[0].serverOptions.options.cwd, folder);
  ({ world } = await activated({
    setting: ['${workspaceFolder}/env/bin/python', '-m', 'mechdsl', 'lsp'], folders: [folder],
  }));
  assert.strictEqual(world.clients[0].serverOptions.command, `${folder}/env/bin/python`);
  assert.deepStrictEqual(world.clients[0].serverOptions.args, ['-m', 'mechdsl', 'lsp']);
  // a bare program name is looked up on PATH, not in the folder
  ({ world } = await activated({ setting: ['mechdsl', 'lsp'], folders: [folder] }));
  assert.strictEqual(world.clients[0].serverOptions.command, 'mechdsl');
});

test('a setting that is not a list of strings falls back to ["mechdsl", "lsp"]', async () => {
  for (const setting of [[], 'mechdsl lsp', [1, 2], [''], null]) {
    const { world } = await activated({ setting });
    assert.strictEqual(world.clients[0].serverOptions.command, 'mechdsl', JSON.stringify(setting));
    assert.deepStrictEqual(world.clients[0].serverOptions.args, ['lsp']);
  }
});

test('a server that cannot start gives an error naming pip install "mechdsl[lsp]"', async () => {
  const { world } = await activated({
    setting: ['/nowhere/mechdsl', 'lsp'],
    startError: new Error('spawn /nowhere/mechdsl ENOENT'),
  });
  assert.strictEqual(world.errors.length, 1);
  const [message] = world.errors;
  assert.ok(message.includes('pip install "mechdsl[lsp]"'), message);
  assert.ok(message.includes('/nowhere/mechdsl lsp'), message);
  assert.ok(message.includes('ENOENT'), message);
  assert.ok(message.includes('mechdsl.server.command'), message);
});

test('a LanguageClient that throws when created gives the same error', async () => {
  const world = makeWorld();
  world.languageclient.LanguageClient = class {
    constructor() {
      throw new Error('No valid VS Code version detected');
    }
  };
  const extension = load(world);
  await extension.activate({ subscriptions: [] });
  assert.strictEqual(world.errors.length, 1);
  assert.ok(world.errors[0].includes('pip install "mechdsl[lsp]"'));
  await extension.deactivate(); // nothing to stop, no throw
});

test('changing the setting restarts the client with the new command', async () => {
  const { world } = await activated();
  assert.strictEqual(world.configListeners.length, 1);
  world.setting = ['/other/mechdsl', 'lsp'];
  await world.configListeners[0]({ affectsConfiguration: (s) => s === 'mechdsl.server.command' });
  assert.strictEqual(world.clients.length, 2);
  assert.ok(world.clients[0].stopped, 'the old client was not stopped');
  assert.strictEqual(world.clients[1].serverOptions.command, '/other/mechdsl');
  assert.ok(world.clients[1].started);
  // another setting changing leaves the client alone
  await world.configListeners[0]({ affectsConfiguration: (s) => s === 'editor.tabSize' });
  assert.strictEqual(world.clients.length, 2);
  assert.ok(!world.clients[1].stopped);
});

// a stand-in for `mechdsl`: `... view FILE --no-browser` prints the view's address line
// on standard error and waits, as mechdsl view does; anything else exits 1
const FAKE = path.join(__dirname, 'fake-mechdsl.js');

test('"mechdsl: open preview" starts the view and opens its page beside the editor', async () => {
  const file = path.resolve('/work/project/crank.mech');
  const { world, extension } = await activated({ setting: [process.execPath, FAKE, 'lsp'] });
  assert.ok(world.commands['mechdsl.openPreview'], 'the command is not registered');
  world.editor = { document: { uri: { scheme: 'file', fsPath: file }, languageId: 'mech' } };
  const url = await world.commands['mechdsl.openPreview']();
  assert.strictEqual(url, 'http://127.0.0.1:4567/t0ken/');
  assert.deepStrictEqual(world.executed, [['simpleBrowser.show', url]]);
  // the same file again: the running view, not a second one
  assert.strictEqual(await world.commands['mechdsl.openPreview'](), url);
  assert.strictEqual(world.executed.length, 2);
  await extension.deactivate();
});

test('a preview that cannot start names pip install "mechdsl[view]"', async () => {
  const { world, extension } = await activated({ setting: [process.execPath, FAKE, 'broken'] });
  world.editor = { document: { uri: { scheme: 'file', fsPath: '/x/a.mech' }, languageId: 'mech' } };
  assert.strictEqual(await world.commands['mechdsl.openPreview'](), undefined);
  assert.strictEqual(world.errors.length, 1);
  assert.ok(world.errors[0].includes('pip install "mechdsl[view]"'), world.errors[0]);
  // not a .mech file on disk: said, nothing started
  world.editor = { document: { uri: { scheme: 'untitled', fsPath: '' }, languageId: 'mech' } };
  await world.commands['mechdsl.openPreview']();
  assert.strictEqual(world.errors.length, 2);
  await extension.deactivate();
});

test('deactivate() stops the client', async () => {
  const { world, extension } = await activated();
  await extension.deactivate();
  assert.ok(world.clients[0].stopped);
});

(async () => {
  let failed = 0;
  for (const { name, fn } of tests) {
    try {
      await fn();
      console.log(`ok - ${name}`);
    } catch (err) {
      failed += 1;
      console.log(`not ok - ${name}\n${err && err.stack ? err.stack : err}`);
    }
  }
  console.log(`${tests.length - failed} passed, ${failed} failed`);
  process.exitCode = failed ? 1 : 0;
})();
