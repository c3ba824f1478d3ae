from bgap.runner.numerics import command

main = command("bgap.commands.watch")
if __name__ == "__main__":
    main()
