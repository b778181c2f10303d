-- A minimal Neovim set-up for .mech files with mechdsl's language server, written for the
-- oldest client still in distributions (Neovim 0.7: vim.lsp.start_client and
-- buf_attach_client; 0.10 and newer can use vim.lsp.start as in docs/editor.md).
-- Used by capture.sh for the README's captured session:
--   nvim --clean -u editors/nvim/init.lua FILE.mech
-- The server command comes from $MECHDSL_LSP (default "mechdsl lsp").
vim.cmd("filetype on")
vim.cmd("syntax off")
vim.o.termguicolors = false
vim.o.signcolumn = "yes"
vim.o.number = true
vim.o.updatetime = 300
vim.o.shortmess = vim.o.shortmess .. "I"

vim.diagnostic.config({ virtual_text = { prefix = "●" }, signs = true, underline = true,
                        float = { border = "single", source = false } })

local server = vim.split(os.getenv("MECHDSL_LSP") or "mechdsl lsp", " ", { trimempty = true })

vim.api.nvim_create_autocmd({ "BufRead", "BufNewFile" }, {
  pattern = "*.mech",
  callback = function(args)
    vim.bo[args.buf].filetype = "mech"
    vim.bo[args.buf].commentstring = "# %s"
    local id = vim.lsp.start_client({
      name = "mechdsl",
      cmd = server,
      root_dir = vim.fn.fnamemodify(vim.api.nvim_buf_get_name(args.buf), ":p:h"),
    })
    if id then
      vim.lsp.buf_attach_client(args.buf, id)
    end
    vim.keymap.set("n", "K", vim.lsp.buf.hover, { buffer = args.buf })
    vim.keymap.set("n", "gd", vim.lsp.buf.definition, { buffer = args.buf })
    vim.keymap.set("n", "gr", vim.lsp.buf.references, { buffer = args.buf })
    vim.keymap.set("n", "<space>rn", vim.lsp.buf.rename, { buffer = args.buf })
    vim.keymap.set("n", "<space>f", vim.lsp.buf.formatting, { buffer = args.buf })
    vim.keymap.set("n", "<space>e", vim.diagnostic.open_float, { buffer = args.buf })
  end,
})
